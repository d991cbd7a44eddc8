"""What the accuracy benchmark evaluates: a design, the depths, and (where needed) a sensor crop.

Each case is one design at three depths (the ends of its range and the focal plane,
or the middle when 0 lies outside), the hardest and the easiest defocus. Fourier
designs computed per lenslet keep the innermost and outermost lenslet of each focal
length (:func:`lenslet_subset`). Fourier designs whose sub-images overlap are computed on the full sensor grid; on a 2048^2
sensor that is minutes per depth at the reference sampling, so those cases use a
centred crop of ``CROP_PIXELS`` (the same crop for every setting and the reference).
The crop is only taken when the array's whole footprint (all lenslets, their
geometric reach) fits inside it; the note says what was cut.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lfm_studio.engine.design import Design, load_preset, resolve_design
from lfm_studio.engine.design.evolve import evolve
from lfm_studio.engine.systems.kinds import FOURIER, SystemKind, kind_of

CROP_PIXELS = 512
"""Sensor side (pixels) of the crop used for full-field Fourier cases."""


@dataclass(frozen=True)
class BenchCase:
    """One design evaluated by the sweep.

    Attributes
    ----------
    name : short label used in tables (the preset name or the file stem).
    design : the design computed (possibly with a cropped sensor).
    depths : source depths in metres.
    note : what was changed from the shipped design (empty when nothing).
    """

    name: str
    design: Design
    depths: tuple[float, ...]
    note: str = ""

    @property
    def kind(self) -> str:
        """The design-file word of the case's system kind (for tables and JSON)."""
        return self.system_kind.name

    @property
    def system_kind(self) -> SystemKind:
        """The case's system kind (:func:`~lfm_studio.engine.systems.kinds.kind_of`)."""
        return kind_of(self.design)


def case_depths(design: Design) -> tuple[float, ...]:
    """``(start, 0, stop)`` of the design's depth range in metres (the middle instead of 0 when outside)."""
    start, stop = (v * 1e-6 for v in design.depths.depth_range_um)
    if start == stop:
        return (start,)
    middle = 0.0 if start < 0.0 < stop else 0.5 * (start + stop)
    return (start, middle, stop)


def _sub_images_overlap(design: Design, depths: tuple[float, ...]) -> bool:
    """Whether lenslet footprints overlap on the sensor for ``design`` (the reference is then the full field)."""
    from lfm_studio.engine.systems.fourier_psf import FourierAccuracy, footprints_overlap
    from lfm_studio.engine.systems.from_design import fourier_system_of

    return footprints_overlap(fourier_system_of(design), depths, FourierAccuracy())


def _array_reach_pixels(design: Design) -> float:
    """Largest distance (pixels) from the sensor centre that lenslet apertures reach."""
    from lfm_studio.engine.systems.fourier_windows import rim_radius
    from lfm_studio.engine.systems.from_design import fourier_system_of

    system = fourier_system_of(design)
    reach = max(max(abs(c) for c in lens.center) + rim_radius(lens) for lens in system.mla.lenslets)
    return reach / system.pixel_pitch


def bench_case(design: Design, name: str | None = None) -> BenchCase:
    """The case for ``design``: its depths, and a sensor crop for full-field Fourier designs."""
    name = name or design.name
    depths = case_depths(design)
    if kind_of(design) is not FOURIER:  # the crop and lenslet subset below are Fourier-path tricks
        return BenchCase(name, design, depths)
    ny, nx = design.camera.pixel_count
    if not _sub_images_overlap(design, depths):
        subset = lenslet_subset(design)
        count, kept = len(design.mla.lenslets), len(subset.mla.lenslets)
        if kept == count:
            return BenchCase(name, design, depths)
        note = (
            f"{kept} of {count} lenslets (innermost and outermost of each focal length; per-lenslet "
            "path, so their worst error bounds the array's; times scale about with the lenslet count)"
        )
        return BenchCase(name, subset, depths, note)
    if min(ny, nx) <= CROP_PIXELS:
        return BenchCase(name, design, depths)
    if 2.0 * _array_reach_pixels(design) > 0.75 * CROP_PIXELS:
        return BenchCase(name, design, depths)
    cropped = evolve(design, "camera.pixel_count", (CROP_PIXELS, CROP_PIXELS))
    note = (
        f"sensor cropped to {CROP_PIXELS} x {CROP_PIXELS} of {ny} x {nx} pixels (sub-images overlap: "
        "full-field reference; the crop holds the whole array's footprint)"
    )
    return BenchCase(name, cropped, depths, note)


def resolve_case(name_or_path: str) -> BenchCase:
    """The case of a preset name or a design file path."""
    design = resolve_design(name_or_path)
    label = name_or_path if "/" not in name_or_path and not name_or_path.endswith(".json") else None
    return bench_case(design, label or design.name)


def shipped_cases() -> list[BenchCase]:
    """One case per shipped preset design."""
    from lfm_studio.engine.design import list_presets

    return [bench_case(load_preset(name), name) for name in list_presets()]


def lenslet_subset(design: Design) -> Design:
    """``design`` with only the innermost and outermost lenslet of each focal length (Fourier).

    On the per-lenslet path each lenslet is computed on its own window; when the windows
    do not overlap, the relative L2 error of the whole stack is at most the worst
    lenslet's, so these extremes (nearest to and farthest from the axis, every focal
    group) bound the error of the full array at a fraction of the cost. Tests use it.
    """
    if kind_of(design) is not FOURIER:
        return design
    lenses = design.mla.lenslets
    keep: list[int] = []
    for focal in sorted({lens.focal_length_mm for lens in lenses}):
        group = [i for i, lens in enumerate(lenses) if lens.focal_length_mm == focal]
        distance = {i: math.hypot(*lenses[i].center_um) for i in group}
        for i in (min(group, key=distance.get), max(group, key=distance.get)):
            if i not in keep:
                keep.append(i)
    if len(keep) == len(lenses):
        return design
    return evolve(design, "mla.lenslets", tuple(lenses[i] for i in sorted(keep)))
