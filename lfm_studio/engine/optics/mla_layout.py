"""Microlens-array layout: lenslets, the validated array, square and hexagonal generators.

A :class:`MicrolensArray` is a tuple of :class:`Lenslet` (centre, aperture, focal
length, shape) plus an optional array aperture (a circle and/or a rectangle centred
on the optical axis, e.g. the pupil footprint). Regular square and hexagonal arrays
and arbitrary layouts are the same object (thesis Algorithm 1 builds its phase mask
from such a list). Invariants are checked at construction: every lenslet lies inside
the array aperture, and no two apertures overlap (touching is allowed). All lengths
in metres; error messages show micrometres.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import torch

from lfm_studio.engine.errors import require_finite, require_positive

SHAPES = ("circle", "square")
# Relative slack (of the larger diameter) for "touching" and "on the rim" tests, so
# that rounding in generated centres does not reject a tight layout.
_TOLERANCE = 1e-9
# Absolute floor of that slack, metres: the 1e-5 um that design files allow (their centres
# are rounded to 1e-6 um; design.mla.TOLERANCE_UM), so every validated design builds here.
_ABSOLUTE_TOLERANCE = 1e-11


def _slack(diameter: float) -> float:
    """Overlap or rim excursion (metres) still counted as touching for apertures of ``diameter``."""
    return max(_TOLERANCE * diameter, _ABSOLUTE_TOLERANCE)


def _um(value: float) -> str:
    return f"{value / 1e-6:.6g}"


@dataclass(frozen=True)
class Lenslet:
    """One microlens.

    Attributes
    ----------
    center : (x, y)
        Lens axis in metres, relative to the optical axis.
    aperture_diameter : float
        Diameter of a circular aperture, or side of a square one, in metres.
    focal_length : float or 0-d tensor
        Focal length in metres (> 0); a tensor makes the MLA phase differentiable in it.
    shape : "circle" or "square"
        Aperture shape (squares are axis aligned).
    """

    center: tuple[float, float]
    aperture_diameter: float
    focal_length: float | torch.Tensor
    shape: str = "circle"

    def __post_init__(self) -> None:
        if len(self.center) != 2:
            raise ValueError(f"Lenslet center must be an (x, y) pair in metres; got {self.center!r}.")
        require_finite("Lenslet center x", self.center[0], "m")
        require_finite("Lenslet center y", self.center[1], "m")
        object.__setattr__(self, "center", (float(self.center[0]), float(self.center[1])))
        require_positive("Lenslet aperture_diameter", self.aperture_diameter, "m", "e.g. 150 * um.")
        object.__setattr__(self, "aperture_diameter", float(self.aperture_diameter))
        require_positive(
            "Lenslet focal_length", self.focal_length, "m", "give a converging lens, e.g. 3 * mm."
        )
        if isinstance(self.focal_length, torch.Tensor):
            if self.focal_length.ndim != 0:
                raise ValueError(
                    f"Lenslet focal_length tensor must be 0-d; got shape {tuple(self.focal_length.shape)}."
                )
        else:
            object.__setattr__(self, "focal_length", float(self.focal_length))
        if self.shape not in SHAPES:
            raise ValueError(f"Lenslet shape must be one of {SHAPES}; got {self.shape!r}.")

    @property
    def half_width(self) -> float:
        """Half the aperture's bounding-box side, in metres."""
        return self.aperture_diameter / 2.0

    def describe(self, index: int) -> str:
        x, y = self.center
        size = "diameter" if self.shape == "circle" else "side"
        return f"lenslet {index} ({self.shape}, centre ({_um(x)}, {_um(y)}) um, {size} {_um(self.aperture_diameter)} um)"


def _overlap_depth(a: Lenslet, b: Lenslet) -> float:
    """How far two apertures interpenetrate, in metres (<= 0: disjoint or touching)."""
    dx, dy = abs(a.center[0] - b.center[0]), abs(a.center[1] - b.center[1])
    if a.shape == b.shape == "circle":
        return a.half_width + b.half_width - math.hypot(dx, dy)
    if a.shape == b.shape == "square":
        reach = a.half_width + b.half_width
        return min(reach - dx, reach - dy)
    circle, square = (a, b) if a.shape == "circle" else (b, a)
    ox, oy = dx - square.half_width, dy - square.half_width
    if ox <= 0.0 and oy <= 0.0:  # circle centre inside the square
        return circle.half_width - max(ox, oy)
    return circle.half_width - math.hypot(max(ox, 0.0), max(oy, 0.0))


def _first_overlap(lenslets: tuple[Lenslet, ...]) -> tuple[int, int, float] | None:
    """First overlapping pair (lowest indices), found with a uniform bucket grid in O(L)."""
    cell = max(lens.aperture_diameter for lens in lenslets)
    buckets: dict[tuple[int, int], list[int]] = {}
    for i, lens in enumerate(lenslets):
        key = (math.floor(lens.center[0] / cell), math.floor(lens.center[1] / cell))
        buckets.setdefault(key, []).append(i)
    found = None
    for (bx, by), members in buckets.items():
        for i in members:
            for ox in (-1, 0, 1):
                for oy in (-1, 0, 1):
                    for j in buckets.get((bx + ox, by + oy), ()):
                        if j <= i:
                            continue
                        a, b = lenslets[i], lenslets[j]
                        depth = _overlap_depth(a, b)
                        overlaps = depth > _slack(max(a.aperture_diameter, b.aperture_diameter))
                        if overlaps and (found is None or (i, j) < found[:2]):
                            found = (i, j, depth)
    return found


def outside_reason(lens: Lenslet, aperture_diameter: float | None, extent: tuple[float, float] | None) -> str:
    """Why ``lens`` does not fit the array aperture ('' when it fits)."""
    x, y = lens.center
    slack = _slack(lens.aperture_diameter)
    if aperture_diameter is not None:
        h = lens.half_width
        reach = math.hypot(x, y) + h if lens.shape == "circle" else math.hypot(abs(x) + h, abs(y) + h)
        if reach > aperture_diameter / 2.0 + slack:
            return (
                f"its edge reaches {_um(reach)} um from the axis, beyond the array aperture radius "
                f"{_um(aperture_diameter / 2.0)} um (aperture_diameter {_um(aperture_diameter)} um)"
            )
    if extent is not None:
        width, height = extent
        if abs(x) + lens.half_width > width / 2.0 + slack or abs(y) + lens.half_width > height / 2.0 + slack:
            return f"it extends beyond the array extent {_um(width)} x {_um(height)} um (centred on the axis)"
    return ""


@dataclass(frozen=True)
class MicrolensArray:
    """A validated set of lenslets.

    Attributes
    ----------
    lenslets : tuple of Lenslet
        At least one; order is preserved (indices in messages refer to it).
    aperture_diameter : float, optional
        Diameter in metres of a circular array aperture centred on the axis.
    extent : (width, height), optional
        Size in metres of a rectangular array area centred on the axis.

    Raises
    ------
    ValueError
        If a lenslet extends beyond the aperture/extent, or two apertures overlap
        (the message names both lenslets, their centres and sizes, and the overlap).
    """

    lenslets: tuple[Lenslet, ...]
    aperture_diameter: float | None = None
    extent: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        lenslets = tuple(self.lenslets)
        object.__setattr__(self, "lenslets", lenslets)
        if not lenslets:
            raise ValueError("MicrolensArray needs at least one lenslet; got none. Fix: add lenslets.")
        for i, lens in enumerate(lenslets):
            if not isinstance(lens, Lenslet):
                raise TypeError(f"MicrolensArray lenslets[{i}] must be a Lenslet; got {type(lens).__name__}.")
        if self.aperture_diameter is not None:
            require_positive("MicrolensArray aperture_diameter", self.aperture_diameter, "m", "or pass None.")
            object.__setattr__(self, "aperture_diameter", float(self.aperture_diameter))
        if self.extent is not None:
            width, height = self.extent
            require_positive("MicrolensArray extent width", width, "m", "or pass extent=None.")
            require_positive("MicrolensArray extent height", height, "m", "or pass extent=None.")
            object.__setattr__(self, "extent", (float(width), float(height)))
        for i, lens in enumerate(lenslets):
            reason = outside_reason(lens, self.aperture_diameter, self.extent)
            if reason:
                raise ValueError(
                    f"{lens.describe(i)} lies outside the array: {reason}. "
                    "Fix: move or shrink the lenslet, or enlarge the array aperture."
                )
        overlap = _first_overlap(lenslets)
        if overlap is not None:
            i, j, depth = overlap
            raise ValueError(
                f"{lenslets[i].describe(i)} and {lenslets[j].describe(j)} overlap by {_um(depth)} um. "
                "Fix: increase the spacing or reduce the aperture diameters (apertures may touch, not overlap)."
            )

    def __len__(self) -> int:
        return len(self.lenslets)

    def __iter__(self) -> Iterator[Lenslet]:
        return iter(self.lenslets)

    def __getitem__(self, index: int) -> Lenslet:
        return self.lenslets[index]

    def centers(self) -> torch.Tensor:
        """Lenslet centres as a float64 tensor ``(L, 2)`` of ``(x, y)`` in metres."""
        return torch.tensor([lens.center for lens in self.lenslets], dtype=torch.float64)

    def focal_lengths(self, device: torch.device | str | None = None) -> torch.Tensor:
        """Focal lengths, float64 tensor ``(L,)`` in metres on ``device`` (differentiable in tensor entries)."""
        values = [
            torch.as_tensor(lens.focal_length, dtype=torch.float64, device=device) for lens in self.lenslets
        ]
        return torch.stack(values)
