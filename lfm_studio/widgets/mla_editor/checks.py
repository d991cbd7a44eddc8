"""What is wrong with a lenslet layout, lenslet by lenslet (Qt-free), for the MLA editor's highlights.

On the MLA plane: apertures that overlap (as :class:`~lfm_studio.engine.design.MLASpec`
refuses) and lenslets outside the pupil image (centre outside: no light, as the
design check refuses; partly outside: vignetted, as it warns). On the sensor: each
lenslet's sub-image is a disc of the sub-image radius centred on the lenslet's axis
times ``magnification`` (1 for both Fourier and conventional LFMs, see
:mod:`lfm_studio.engine.design.checks`); sub-images that overlap, leave the sensor
or are cut by its edge.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

from lfm_studio.engine.design import LensletSpec
from lfm_studio.engine.design.errors import fmt
from lfm_studio.engine.design.geometry import candidate_pairs, disc_overlaps
from lfm_studio.engine.design.lenslet import overlap_depth_um
from lfm_studio.engine.design.mla import TOLERANCE_UM

Point = tuple[float, float]
_PAIR = re.compile(r"lenslet (\d+) by")


def _note(issues: dict[int, list[str]], i: int, text: str) -> None:
    issues.setdefault(i, []).append(text)


def mla_issues(lenslets: Sequence[LensletSpec], pupil_radius_um: float | None) -> dict[int, list[str]]:
    """Reasons per lenslet index: overlapping apertures, outside or partly outside the pupil."""
    issues: dict[int, list[str]] = {}
    if not lenslets:
        return issues
    reach = max(lens.aperture_diameter_um for lens in lenslets) + TOLERANCE_UM
    for i, j in candidate_pairs([lens.center_um for lens in lenslets], reach):
        depth = overlap_depth_um(lenslets[i], lenslets[j])
        if depth > TOLERANCE_UM:
            _note(issues, i, f"overlaps lenslet {j} by {fmt(depth)} µm")
            _note(issues, j, f"overlaps lenslet {i} by {fmt(depth)} µm")
    if pupil_radius_um is not None:
        r = fmt(pupil_radius_um)
        for i, lens in enumerate(lenslets):
            distance = math.hypot(*lens.center_um)
            if distance > pupil_radius_um:
                _note(
                    issues, i, f"centre {fmt(distance)} µm from the axis, outside the pupil (radius {r} µm)"
                )
            elif lens.reach_um > pupil_radius_um + TOLERANCE_UM:
                _note(
                    issues,
                    i,
                    f"reaches {fmt(lens.reach_um)} µm, beyond the pupil radius {r} µm (vignetted)",
                )
    return issues


@dataclass(frozen=True)
class SensorLayout:
    """Where the sub-images land on the sensor.

    Attributes
    ----------
    centers_um : sub-image centres on the sensor, micrometres, one per lenslet.
    radius_um : sub-image radius, micrometres.
    overlaps : ``(i, j, depth_um)`` for each pair of overlapping sub-images.
    issues : reasons per lenslet index (overlap, off the sensor, cut by its edge).
    """

    centers_um: tuple[Point, ...]
    radius_um: float
    overlaps: tuple[tuple[int, int, float], ...] = ()
    issues: dict[int, list[str]] = field(default_factory=dict)


def sensor_layout(
    lenslets: Sequence[LensletSpec],
    *,
    sub_image_radius_um: float,
    sensor_size_um: tuple[float, float] | None,
    magnification: float = 1.0,
    tolerance_um: float | None = None,
    checks: bool = True,
) -> SensorLayout:
    """Sub-image discs of ``lenslets`` on a sensor ``(width, height)`` um centred on the axis.

    Overlaps and edge cuts shallower than ``tolerance_um`` are ignored: pass half a
    camera pixel, as the design checks do; the default, 0.1 % of the sub-image radius,
    ignores the rounding of sub-images that tile exactly. ``checks=False``: only the
    centres (for a fast preview).
    """
    r = float(sub_image_radius_um)
    if tolerance_um is None:
        tolerance_um = 1e-3 * r
    centers = tuple((magnification * x, magnification * y) for x, y in (lens.center_um for lens in lenslets))
    issues: dict[int, list[str]] = {}
    if not checks:
        return SensorLayout(centers, r)
    overlaps = tuple(disc_overlaps(centers, r, tolerance_um)) if r > 0 else ()  # grid search, O(n)
    for i, j, depth in overlaps:
        _note(issues, i, f"sub-image overlaps that of lenslet {j} by {fmt(depth)} µm")
        _note(issues, j, f"sub-image overlaps that of lenslet {i} by {fmt(depth)} µm")
    if sensor_size_um is not None:
        half_w, half_h = sensor_size_um[0] / 2.0, sensor_size_um[1] / 2.0
        size = f"{fmt(sensor_size_um[0])} x {fmt(sensor_size_um[1])} µm sensor"
        for i, (x, y) in enumerate(centers):
            if abs(x) > half_w or abs(y) > half_h:
                _note(issues, i, f"sub-image centred off the {size}")
            elif abs(x) + r > half_w + tolerance_um or abs(y) + r > half_h + tolerance_um:
                _note(issues, i, f"sub-image cut by the edge of the {size}")
    return SensorLayout(centers, r, overlaps, issues)


def summary(issues: dict[int, list[str]], *, limit: int = 3) -> str:
    """One line for a status bar: ``lenslet 3 overlaps lenslet 4 by 12 um; ... (+2 more)``."""
    lines = [
        f"lenslet {i} {text}"
        for i in sorted(issues)
        for text in issues[i]
        if not ((m := _PAIR.search(text)) and int(m.group(1)) < i)  # said already for the other one
    ]
    shown = "; ".join(lines[:limit])
    return shown if len(lines) <= limit else f"{shown}; (+{len(lines) - limit} more)"
