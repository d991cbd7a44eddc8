"""Lenslet centres of regular and multifocal layouts, in micrometres.

Pure geometry, no specs: the :class:`~lfm_studio.engine.design.mla.MLASpec`
helpers and :class:`~lfm_studio.engine.design.mla.RegularMLASpec` build lenslets
from these centres. Lattices are ordered row by row (increasing y), then by
increasing x, like :mod:`lfm_studio.engine.optics.mla_generators`. Centres are
rounded to 1e-6 um (1 pm) so files stay readable; rounding is symmetric, so
symmetric layouts stay exactly symmetric.
"""

from __future__ import annotations

import math
from typing import Literal

from lfm_studio.engine.design.errors import DesignError

Point = tuple[float, float]
SQRT3_2 = math.sqrt(3.0) / 2.0


def _round(value: float) -> float:
    return round(value, 6) + 0.0  # + 0.0 turns -0.0 into 0.0


def square_sites(
    pitch_um: float,
    shape: tuple[int, int],
    offset_um: Point = (0.0, 0.0),
    limit: tuple[int, int] | None = None,
) -> list[Point]:
    """``ny x nx`` square lattice centred on ``offset_um`` (a site on it when both counts are odd).

    ``limit=(ry, rx)`` returns only the sites of the first ``ry`` rows and ``rx`` columns.
    """
    ny, nx = shape
    ry, rx = limit or shape
    ox, oy = offset_um
    return [
        (_round(ox + (j - (nx - 1) / 2.0) * pitch_um), _round(oy + (i - (ny - 1) / 2.0) * pitch_um))
        for i in range(min(ry, ny))
        for j in range(min(rx, nx))
    ]


def hex_rect_sites(
    pitch_um: float,
    shape: tuple[int, int],
    offset_um: Point = (0.0, 0.0),
    limit: tuple[int, int] | None = None,
) -> list[Point]:
    """``ny`` rows of ``nx`` sites, rows ``pitch sqrt(3)/2`` apart, alternate rows shifted by ``pitch/2``.

    Even rows sit ``pitch/4`` left and odd rows ``pitch/4`` right of the centred
    position, so the patch's bounding box is centred on ``offset_um``. ``limit`` as
    in :func:`square_sites`.
    """
    ny, nx = shape
    ry, rx = limit or shape
    ox, oy = offset_um
    sites: list[Point] = []
    for i in range(min(ry, ny)):
        shift = pitch_um / 4.0 * (1.0 if i % 2 else -1.0) if ny > 1 else 0.0
        y = oy + (i - (ny - 1) / 2.0) * pitch_um * SQRT3_2
        sites.extend(
            (_round(ox + shift + (j - (nx - 1) / 2.0) * pitch_um), _round(y)) for j in range(min(rx, nx))
        )
    return sites


def hex_ring_sites(pitch_um: float, rings: int, offset_um: Point = (0.0, 0.0)) -> list[Point]:
    """Hexagonal patch of ``1 + 3 rings (rings + 1)`` sites around a central site at ``offset_um``.

    Site ``(q, r)`` sits at ``offset + pitch (q + r/2, r sqrt(3)/2)``: six neighbours at ``pitch``.
    """
    if isinstance(rings, bool) or not isinstance(rings, int) or rings < 0:
        raise DesignError(f"rings must be an integer >= 0; got {rings!r}. Fix: e.g. 2 for 19 lenslets.")
    ox, oy = offset_um
    return [
        (_round(ox + pitch_um * (q + r / 2.0)), _round(oy + pitch_um * r * SQRT3_2))
        for r in range(-rings, rings + 1)
        for q in range(-rings, rings + 1)
        if max(abs(q), abs(r), abs(q + r)) <= rings
    ]


def hex_shells(pitch_um: float, count: int, center: Literal["lenslet", "triangle"]) -> list[list[Point]]:
    """The ``count`` hexagonal-lattice sites nearest the axis, grouped in shells of equal radius.

    Shells are ordered by radius, sites within a shell by angle from +x
    (counter-clockwise, in ``[0, 2 pi)``). ``center="lenslet"`` puts a site on the
    axis (shells of 1, 6, 6, 6, 12, ...); ``"triangle"`` puts the axis at the centroid
    of three sites (shells of 3, 3, 6, 6, 3, 6, ...: 3-fold symmetric).
    ``count`` must complete a shell, so the layout keeps the lattice's symmetry.
    """
    if center not in ("lenslet", "triangle"):
        raise DesignError(f"center must be 'lenslet' or 'triangle'; got {center!r}.")
    cx, cy = (0.0, 0.0) if center == "lenslet" else (0.5, SQRT3_2 / 3.0)
    extent = math.isqrt(max(count, 1)) + 3
    by_radius: dict[float, list[tuple[float, Point]]] = {}
    for r in range(-extent, extent + 1):
        for q in range(-extent, extent + 1):
            x, y = q + r / 2.0 - cx, r * SQRT3_2 - cy
            angle = math.atan2(y, x) % (2.0 * math.pi)
            by_radius.setdefault(round(math.hypot(x, y), 9), []).append((angle, (x, y)))
    shells, total, totals = [], 0, []
    for radius in sorted(by_radius):
        if total >= count:
            break
        shell = sorted(by_radius[radius])
        shells.append([(_round(pitch_um * x), _round(pitch_um * y)) for _, (x, y) in shell])
        total += len(shell)
        totals.append(total)
    if total != count:
        raise DesignError(
            f"count {count} splits a shell of the hexagonal lattice centred on a {center}; complete-shell counts "
            f"are {', '.join(map(str, totals))}, .... Fix: use one of them so the layout stays symmetric."
        )
    return shells
