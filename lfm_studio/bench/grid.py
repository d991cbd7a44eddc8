"""The volume-grid rows of the bench: what a finer reconstruction grid costs and buys.

The volume grid (``accuracy.voxels_per_lenslet`` for a conventional LFM,
``accuracy.volume_oversampling`` for a Fourier one) changes the PSF's shape (more
lenslet sub-positions, or a finer virtual sensor), so its PSF cannot be compared with
the reference of the other rows: the PSF error of these rows is "n/a (other grid)".
Instead each grid value gets

- a time: simulate the PSF at the case's depths with the standard preset on that grid,
  then build the projector (:func:`~lfm_studio.engine.simulation.imaging_setup`), timed
  in the same interleaved rounds as the other rows; its ratio is taken to the default
  grid's time (the ``(standard)`` row of the same knob), since the other rows time the PSF alone;
- a quality number comparable across grids: the reconstructed two-point resolution
  (:func:`~lfm_studio.engine.performance.reconstructed.reconstructed_resolution`,
  lateral and axial, noise free, plain RL) at the case's middle depth on a cropped
  sensor. It is a length in micrometres, so grids of different voxels are compared directly;
  ``inf`` when no separation up to the largest tried resolves.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from lfm_studio.bench.cases import BenchCase
from lfm_studio.engine.design import AccuracySpec, Design
from lfm_studio.engine.design.evolve import evolve
from lfm_studio.engine.systems.kinds import CONVENTIONAL, FOURIER, SystemKind

GRID_KNOBS: dict[SystemKind, tuple[str, tuple[int, ...]]] = {
    CONVENTIONAL: ("voxels_per_lenslet", (3, 5, 7)),
    FOURIER: ("volume_oversampling", (1, 3)),
}
"""Per system kind: the grid knob and the values swept (the default is always included)."""

GRID_KNOB_NAMES = frozenset(knob for knob, _ in GRID_KNOBS.values())
NOT_COMPARABLE = "n/a (other grid)"
"""What the PSF and reconstruction error columns show for a grid row."""

RESOLUTION_CROP = 256  # camera pixels kept about the axis for the resolution measure
RESOLUTION_ITERATIONS = 50  # plain RL iterations of the resolution measure
MAX_LATERAL = 20e-6  # largest lateral separation tried, m
MAX_AXIAL = 30e-6  # largest axial separation tried, m


@dataclass(frozen=True)
class GridSetting:
    """One volume-grid value: the case's design with the standard preset on that grid."""

    knob: str
    value: str
    design: Design
    default: bool

    @property
    def label(self) -> str:
        """``knob=value``."""
        return f"{self.knob}={self.value}"


@dataclass(frozen=True)
class GridQuality:
    """The reconstructed two-point resolution of one grid setting (micrometres; inf: unresolved)."""

    lateral_um: float
    axial_um: float
    voxel_um: float
    depth_step_um: float
    depth_um: float

    @property
    def note(self) -> str:
        """The table note: the grid, the depth, and why the PSF error is not given."""
        return (
            f"voxel {self.voxel_um:.3g} um (floor {2 * self.voxel_um:.3g}), dz {self.depth_step_um:.3g} um; "
            f"two-point resolution at {self.depth_um:g} um after RL; time = PSF + projector set-up; "
            "PSF error n/a: another grid gives a PSF of another shape"
        )


def grid_settings(case: BenchCase, *, quick: bool = False) -> list[GridSetting]:
    """The grid values of ``case``'s kind on the standard preset (none for ``quick``)."""
    if quick:
        return []
    knob, values = GRID_KNOBS[case.system_kind]
    base = AccuracySpec.from_preset("standard")
    default = getattr(base, knob)
    out = []
    for v in sorted({*values, default}):
        design = evolve(case.design, "accuracy", base.model_validate({**base.model_dump(), knob: v}))
        text = f"{v} (standard)" if v == default else str(v)
        out.append(GridSetting(knob, text, design, v == default))
    return out


def grid_task(case: BenchCase, setting: GridSetting) -> Callable[[], object]:
    """The timed work of a grid row: the PSF at the case's depths, then the projector set-up."""
    from lfm_studio.engine.simulation import imaging_setup, simulate_psf

    return lambda: imaging_setup(simulate_psf(setting.design, depths=case.depths))


def grid_quality(
    case: BenchCase,
    setting: GridSetting,
    *,
    iterations: int = RESOLUTION_ITERATIONS,
    crop: int | None = RESOLUTION_CROP,
) -> GridQuality:
    """Two-point resolution (lateral, axial) of ``setting`` at the case's middle depth.

    Noise free, plain RL with ``iterations`` iterations, ``crop`` camera pixels about the axis.
    """
    from lfm_studio.engine.performance.reconstructed import reconstructed_resolution

    depth = case.depths[len(case.depths) // 2]
    report = reconstructed_resolution(
        setting.design,
        (depth,),
        iterations=iterations,
        crop=crop,
        max_lateral=MAX_LATERAL,
        max_axial=MAX_AXIAL,
    )
    (result,) = report.depths

    def um(value: float | None) -> float:
        return math.inf if value is None else value / 1e-6

    return GridQuality(
        um(result.lateral),
        um(result.axial),
        report.lateral_voxel / 1e-6,
        report.axial_voxel / 1e-6,
        depth / 1e-6,
    )
