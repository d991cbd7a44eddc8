"""Where the MLA editor's Add button puts a lenslet (Qt-free): the free spot nearest the view centre.

A free spot leaves the new lenslet (and its symmetric partners) clear of every existing
aperture and, when the pupil is known, inside it. Lattice sites come first: an existing
centre plus one of the layout's nearest-neighbour steps, so a square or hex array grows by
one cell; when none is free, points of a grid half a diameter apart around the view
centre. The caller builds the lenslet like the selected (or last) one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from lfm_studio.engine.design import LensletSpec
from lfm_studio.engine.design.geometry import candidate_pairs
from lfm_studio.engine.design.lenslet import overlap_depth_um
from lfm_studio.engine.design.mla import TOLERANCE_UM
from lfm_studio.widgets.mla_editor.model import NO_SYMMETRY, lenslet, snap
from lfm_studio.widgets.mla_editor.symmetry import Point, Symmetry, round_point

NEIGHBOUR_SLACK = 1.05  # steps up to 5 % longer than the shortest one count as nearest neighbours
SEARCH_RINGS = 60  # the fallback grid: at most this many half-diameter steps from the view centre


class _Occupied:
    """The existing apertures, bucketed on a grid of the largest diameter: O(1) overlap queries."""

    def __init__(self, lenslets: Sequence[LensletSpec], new_diameter_um: float) -> None:
        self._lenslets = lenslets
        self._cell = max([new_diameter_um, *(lens.aperture_diameter_um for lens in lenslets)])
        self._buckets: dict[tuple[int, int], list[int]] = {}
        for i, lens in enumerate(lenslets):
            self._buckets.setdefault(self._key(lens.center_um), []).append(i)

    def _key(self, p: Point) -> tuple[int, int]:
        return math.floor(p[0] / self._cell), math.floor(p[1] / self._cell)

    def clear_of(self, new: LensletSpec) -> bool:
        kx, ky = self._key(new.center_um)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                for i in self._buckets.get((kx + dx, ky + dy), ()):
                    if overlap_depth_um(new, self._lenslets[i]) > TOLERANCE_UM:
                        return False
        return True


def lattice_sites(lenslets: Sequence[LensletSpec]) -> list[Point]:
    """Each centre plus each nearest-neighbour step of the layout (both directions), without the centres."""
    centers = [lens.center_um for lens in lenslets]
    reach = 2.0 * max((lens.aperture_diameter_um for lens in lenslets), default=0.0)
    steps = [
        (centers[j][0] - centers[i][0], centers[j][1] - centers[i][1])
        for i, j in candidate_pairs(centers, reach)
    ]
    steps = [s for s in steps if math.hypot(*s) > TOLERANCE_UM]
    if not steps:
        return []
    shortest = min(math.hypot(*s) for s in steps)
    unique = {round_point(s) for s in steps if math.hypot(*s) <= NEIGHBOUR_SLACK * shortest}
    unique |= {round_point((-x, -y)) for x, y in unique}
    taken = {round_point(c) for c in centers}
    sites = {round_point((c[0] + x, c[1] + y)) for c in centers for x, y in unique}
    return sorted(sites - taken)


def _grid_around(near: Point, step: float, pupil_radius_um: float | None) -> list[Point]:
    rings = SEARCH_RINGS
    if pupil_radius_um is not None:  # no point beyond the pupil's far side
        rings = min(rings, math.ceil((pupil_radius_um + math.hypot(*near)) / step))
    return [
        (near[0] + i * step, near[1] + j * step)
        for i in range(-rings, rings + 1)
        for j in range(-rings, rings + 1)
    ]


def free_spot(
    lenslets: Sequence[LensletSpec],
    *,
    diameter_um: float,
    focal_length_mm: float,
    shape: str,
    near: Point,
    pupil_radius_um: float | None,
    symmetry: Symmetry = NO_SYMMETRY,
    snap_pitch_um: float | None = None,
) -> Point | None:
    """The free spot for a new lenslet nearest ``near`` (lattice sites first), or None if there is none.

    With ``snap_pitch_um`` candidates are snapped to that grid first; with a ``symmetry`` every
    partner must be free too.
    """
    occupied = _Occupied(lenslets, diameter_um)

    def fits(p: Point) -> bool:
        placed: list[LensletSpec] = []
        for q in symmetry.orbit(p):
            new = lenslet(q, diameter_um, focal_length_mm, shape)
            if pupil_radius_um is not None and new.reach_um > pupil_radius_um + TOLERANCE_UM:
                return False
            if not occupied.clear_of(new) or any(overlap_depth_um(new, o) > TOLERANCE_UM for o in placed):
                return False
            placed.append(new)
        return True

    by_distance = lambda p: (math.dist(p, near), p)  # noqa: E731 - ties broken by position: deterministic
    for candidates in (lattice_sites(lenslets), _grid_around(near, diameter_um / 2.0, pupil_radius_um)):
        if snap_pitch_um is not None:
            candidates = [snap(p, snap_pitch_um) for p in candidates]
        if pupil_radius_um is not None:
            candidates = [p for p in candidates if math.hypot(*p) <= pupil_radius_um]
        for p in sorted(candidates, key=by_distance):
            if fits(p):
                return round_point(p)
    return None
