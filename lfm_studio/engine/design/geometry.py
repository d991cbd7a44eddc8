"""Pair search for overlap checks: which of many shapes can touch, in O(N) not O(N^2).

Centres are binned in a uniform grid of cell size ``reach`` (the largest distance
at which two shapes can still overlap); only shapes in the same or adjacent cells
are compared. A conventional LFM has thousands of lenslets, so this matters.
"""

from __future__ import annotations

import math
from collections.abc import Sequence


def candidate_pairs(centers: Sequence[tuple[float, float]], reach: float) -> list[tuple[int, int]]:
    """Index pairs ``(i, j)``, ``i < j``, of centres closer than ``reach`` along both axes, sorted.

    Parameters
    ----------
    centers : sequence of (x, y)
        Centres in any one length unit.
    reach : float
        Largest centre distance at which two shapes can overlap, same unit (> 0).
    """
    if not centers:
        return []
    buckets: dict[tuple[int, int], list[int]] = {}
    for i, (x, y) in enumerate(centers):
        buckets.setdefault((math.floor(x / reach), math.floor(y / reach)), []).append(i)
    pairs = []
    for (bx, by), members in buckets.items():
        for ox in (-1, 0, 1):
            for oy in (-1, 0, 1):
                for j in buckets.get((bx + ox, by + oy), ()):
                    for i in members:
                        if i < j:
                            dx, dy = abs(centers[i][0] - centers[j][0]), abs(centers[i][1] - centers[j][1])
                            if dx < reach and dy < reach:
                                pairs.append((i, j))
    return sorted(pairs)


def disc_overlaps(
    centers: Sequence[tuple[float, float]], radius: float, tolerance: float
) -> list[tuple[int, int, float]]:
    """Pairs of equal discs that overlap by more than ``tolerance``: ``(i, j, depth)``, sorted.

    ``depth = 2 radius - distance`` in the unit of the inputs.
    """
    found = []
    for i, j in candidate_pairs(centers, 2.0 * radius):
        depth = 2.0 * radius - math.dist(centers[i], centers[j])
        if depth > tolerance:
            found.append((i, j, depth))
    return found


def list_pairs(pairs: Sequence[str], limit: int = 6) -> str:
    """Join pair descriptions for a message, at most ``limit`` of them, then ``and N more``."""
    shown = "; ".join(pairs[:limit])
    return shown if len(pairs) <= limit else f"{shown}; and {len(pairs) - limit} more"
