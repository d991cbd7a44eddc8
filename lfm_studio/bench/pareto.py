"""The Pareto front of (time, error) points: the settings no other setting beats on both."""

from __future__ import annotations

from collections.abc import Sequence


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the non-dominated points of ``points = [(time, error), ...]``, fastest first.

    A point is dominated when another is at least as fast and at least as accurate and
    strictly better in one of the two. Equal points are all kept. NaN points are never
    on the front.
    """
    valid = [i for i, (t, e) in enumerate(points) if t == t and e == e]
    front = []
    for i in valid:
        ti, ei = points[i]
        dominated = any(
            points[j][0] <= ti and points[j][1] <= ei and (points[j][0] < ti or points[j][1] < ei)
            for j in valid
        )
        if not dominated:
            front.append(i)
    return sorted(front, key=lambda i: (points[i][0], points[i][1]))
