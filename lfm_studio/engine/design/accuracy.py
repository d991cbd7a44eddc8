"""Accuracy settings: every numerical knob of a simulation, explicit, with named presets.

A preset ("preview", "standard", "reference") is a starting point: keys missing from
a design file are filled from the named preset, and the knob values are what the
engine uses. ``preset`` records where the values came from ("custom" for a set made
by hand); :meth:`AccuracySpec.matches_preset` says whether they were edited since.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import model_validator

from lfm_studio.engine.design.base import SpecModel
from lfm_studio.engine.design.errors import DesignError, fmt

PresetName = Literal["preview", "standard", "reference", "custom"]
Propagator = Literal["auto", "asm", "bandlimited_asm", "fresnel_tf", "fresnel_ir"]

ACCURACY_PRESETS: dict[str, dict[str, Any]] = {
    # Fast look while editing: paraxial objective, no oversampling, little padding.
    "preview": dict(
        propagator="auto", oversampling=1, padding=1.5, dtype="float32",
        debye_points=32, objective_model="paraxial", per_lenslet=True, depth_chunk=8,
    ),
    # Default: Debye objective, 2x oversampled grids, 2x padding (DESIGN.md section 3).
    "standard": dict(
        propagator="auto", oversampling=2, padding=2.0, dtype="float32",
        debye_points=64, objective_model="debye", per_lenslet=True, depth_chunk=4,
    ),
    # Ground truth for benchmarks: band-limited ASM, float64, fine quadrature, full grid.
    "reference": dict(
        propagator="bandlimited_asm", oversampling=4, padding=2.0, dtype="float64",
        debye_points=256, objective_model="debye", per_lenslet=False, depth_chunk=1,
    ),
}  # fmt: skip


class AccuracySpec(SpecModel):
    """Numerical settings of a simulation (none of them changes the optics).

    Attributes
    ----------
    preset : "preview", "standard", "reference" or "custom"
        Preset the knobs started from; missing knobs are filled from it.
    propagator : "auto", "asm", "bandlimited_asm", "fresnel_tf" or "fresnel_ir"
        Free-space propagation method ("auto" chooses from the Fresnel number and sampling).
    oversampling : int
        Simulation grid points per camera pixel along each axis (>= 1).
    padding : float
        Grid size factor applied before propagating (>= 1; 2 avoids wrap-around).
    dtype : "float32" or "float64"
        Real precision (complex64 / complex128 fields).
    debye_points : int
        Gauss-Legendre points in theta for the Debye integral (>= 8).
    objective_model : "paraxial" or "debye"
        Paraxial 4f imaging (low NA) or the Debye integral (high NA).
    per_lenslet : bool
        Fourier LFM: compute each lenslet's sub-image on its own small grid (exact
        only when sub-images do not overlap).
    depth_chunk : int
        Depths per FFT batch (>= 1; small on CPU to stay in cache, large on GPU).
    """

    preset: PresetName = "standard"
    propagator: Propagator
    oversampling: int
    padding: float
    dtype: Literal["float32", "float64"]
    debye_points: int
    objective_model: Literal["paraxial", "debye"]
    per_lenslet: bool
    depth_chunk: int

    @model_validator(mode="before")
    @classmethod
    def _fill_from_preset(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        name = data.get("preset", "standard")
        if name == "custom":
            return data
        if name not in ACCURACY_PRESETS:
            raise DesignError(
                f"accuracy preset must be one of {[*ACCURACY_PRESETS, 'custom']}; got {name!r}. Fix: e.g. 'standard'."
            )
        return {**ACCURACY_PRESETS[name], **data}

    @model_validator(mode="after")
    def _check(self) -> AccuracySpec:
        if self.oversampling < 1:
            raise DesignError(f"oversampling must be an integer >= 1; got {self.oversampling}. Fix: e.g. 2.")
        if not self.padding >= 1.0 or self.padding > 16.0:
            raise DesignError(f"padding must be in [1, 16]; got {fmt(self.padding)}. Fix: e.g. 2.")
        if self.debye_points < 8:
            raise DesignError(f"debye_points must be >= 8; got {self.debye_points}. Fix: e.g. 64.")
        if self.depth_chunk < 1:
            raise DesignError(f"depth_chunk must be >= 1; got {self.depth_chunk}. Fix: e.g. 4.")
        return self

    @classmethod
    def from_preset(cls, name: str) -> AccuracySpec:
        """The knob values of preset ``name``."""
        return cls(preset=name)

    def matches_preset(self) -> bool:
        """Whether every knob still has its preset's value (False for "custom")."""
        values = ACCURACY_PRESETS.get(self.preset)
        return values is not None and all(getattr(self, k) == v for k, v in values.items())
