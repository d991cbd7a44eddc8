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
    # Fast look while editing: 1 sub-sample per pixel, exact (Fourier) pixel integration, Debye
    # objective (the paraxial one costs the same and is off by 13-98 %).
    "preview": dict(
        propagator="auto", oversampling=1, pixel_integration="fourier", padding=1.5, dtype="float32",
        debye_points=32, objective_model="debye", per_lenslet=True, depth_chunk=8,
    ),
    # Default: 2 sub-samples per pixel (enough for the intensity's band limit), float32.
    "standard": dict(
        propagator="auto", oversampling=2, pixel_integration="fourier", padding=2.0, dtype="float32",
        debye_points=64, objective_model="debye", per_lenslet=True, depth_chunk=4,
    ),
    # For benchmarks and checks: 3 sub-samples per pixel, float64, band-limited ASM where a
    # full field is computed. Per lenslet when sub-images do not overlap.
    "reference": dict(
        propagator="bandlimited_asm", oversampling=3, pixel_integration="fourier", padding=2.0,
        dtype="float64", debye_points=256, objective_model="debye", per_lenslet=True, depth_chunk=4,
    ),
}  # fmt: skip

PRESET_ERROR_BOUNDS: dict[str, dict[str, float]] = {
    "fourier": {"preview": 0.05, "standard": 0.01, "reference": 0.001},
    "conventional": {"preview": 0.05, "standard": 0.01, "reference": 0.005},
}
"""Worst-depth relative L2 error of each preset's PSF stack against the converged reference,
per system kind (``lfm-studio bench``, docs/benchmarks.md; tested on every shipped design)."""


def describe_preset(name: str) -> str:
    """One line on preset ``name``: its main knobs and its tested PSF error bounds (for tooltips)."""
    knobs = ACCURACY_PRESETS[name]
    model = {"debye": "Debye", "paraxial": "paraxial"}[knobs["objective_model"]]
    bounds = ", ".join(
        f"{100 * PRESET_ERROR_BOUNDS[kind][name]:g} % ({label} LFM)"
        for kind, label in (("fourier", "Fourier"), ("conventional", "conventional"))
    )
    return f"{name}: oversampling {knobs['oversampling']}, {knobs['dtype']}, {model} objective; PSF error <= {bounds}"


class AccuracySpec(SpecModel):
    """Numerical settings of a simulation (none of them changes the optics).

    Attributes
    ----------
    preset : "preview", "standard", "reference" or "custom"
        Preset the knobs started from; missing knobs are filled from it.
    propagator : "auto", "asm", "bandlimited_asm", "fresnel_tf" or "fresnel_ir"
        Free-space propagation method ("auto" chooses from the Fresnel number and sampling).
    oversampling : int
        Simulation grid points per camera pixel along each axis (>= 1). Conventional LFM:
        sensor-field sub-samples per pixel, ``2^o + 1`` with the midpoint rule, those of 1.4
        (o <= 2) or 2.8 (o = 3) samples per intensity Nyquist interval with the exact integral
        (:func:`~lfm_studio.engine.systems.from_design.conventional_accuracy_of`).
    pixel_integration : "fourier" or "midpoint"
        How a pixel's power is taken from its sub-samples (Fourier and conventional LFM): the
        exact box integral of the band-limited intensity ("fourier") or their sum ("midpoint",
        error ~ 1/s^2).
    padding : float
        Grid size factor applied before propagating (>= 1; 2 avoids wrap-around).
    dtype : "float32" or "float64"
        Real precision (complex64 / complex128 fields).
    debye_points : int
        Gauss-Legendre points in theta for the Debye integral (>= 8). Kept for files and
        scripts, but not used by the simulation: the Fourier pupil field is closed form, and
        the conventional NIP field always takes the engine's converged order for its phase
        excursion (fixed orders of 48-96 points measured 41-127 % PSF error on the shipped designs;
        docs/benchmarks.md). Engine scripts can still set ``ConventionalAccuracy.debye_points``.
    objective_model : "paraxial" or "debye"
        Paraxial 4f imaging (low NA) or the Debye integral (high NA).
    per_lenslet : bool
        Fourier LFM: compute each lenslet's sub-image on its own small grid; where
        sub-images overlap, the cheaper of the lenslets' complex fields summed on a shared
        grid and the full field on the sensor crop the lenslets' light covers (always the
        latter with an exact propagator). False: always the full field on the whole sensor.
    depth_chunk : int
        Depths per FFT batch (>= 1; small on CPU to stay in cache, large on GPU).
    voxels_per_lenslet : int
        Conventional LFM: lateral volume voxels per lenslet pitch (odd, >= 1; default 5). The
        voxel is ``pitch / (M voxels_per_lenslet)``; two emitters closer than 2 voxels can
        never show a dip, and the PSF patterns cost grows as its square. Not part of the presets.
    volume_oversampling : int
        Fourier LFM: volume voxels per sensor pixel ``k`` (odd: 1, 3, 5 or 7; default 1). The
        voxel is ``pixel / (M_T k)``; the PSF is sampled on a ``k``-times finer virtual sensor and
        the forward model sums ``k x k`` of its pixels into one camera pixel (exact: the pixel
        integral is additive). Odd, so that a virtual pixel is centred on the axis as the
        camera pixel it belongs to. Cost: ``k^2`` PSF pixels and volume voxels. Not part of the presets.
    """

    preset: PresetName = "standard"
    propagator: Propagator
    oversampling: int
    pixel_integration: Literal["fourier", "midpoint"]
    padding: float
    dtype: Literal["float32", "float64"]
    debye_points: int
    objective_model: Literal["paraxial", "debye"]
    per_lenslet: bool
    depth_chunk: int
    voxels_per_lenslet: int = 5
    volume_oversampling: int = 1

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
        if self.voxels_per_lenslet < 1 or self.voxels_per_lenslet % 2 == 0:
            raise DesignError(
                f"voxels_per_lenslet must be an odd integer >= 1 (a voxel on each lenslet centre); "
                f"got {self.voxels_per_lenslet}. Fix: e.g. 5 (default) or 7."
            )
        if self.volume_oversampling not in (1, 3, 5, 7):
            raise DesignError(
                f"volume_oversampling must be 1, 3, 5 or 7 (odd volume voxels per sensor pixel); "
                f"got {self.volume_oversampling}. Fix: 1 (voxel = pixel / magnification) or 3."
            )
        return self

    @classmethod
    def from_preset(cls, name: str) -> AccuracySpec:
        """The knob values of preset ``name``."""
        return cls.model_validate({"preset": name})

    def matches_preset(self) -> bool:
        """Whether every knob still has its preset's value (False for "custom")."""
        values = ACCURACY_PRESETS.get(self.preset)
        return values is not None and all(getattr(self, k) == v for k, v in values.items())
