"""The MLA plane as a grid of cells of the minimum lenslet size (thesis Algorithm 2, line 1).

Geometry
--------
The plane searched is the pupil footprint on the MLA (Fourier LFM:
``Design.pupil_diameter_at_mla``, diameter ``D`` in micrometres) or, for a
conventional LFM, a diameter the caller gives. It is divided into ``M x M`` square
cells of side ``d_min`` (the minimum lenslet size), ``M = floor(D / d_min)``, centred
on the optical axis. Cell ``(i, j)`` spans ``x`` in ``[(i - M/2) d_min, (i + 1 - M/2) d_min)``
and ``y`` likewise with ``j`` (``i`` counts columns along x, ``j`` rows along y).

A lenslet is a :class:`Block`: ``size x size`` merged cells with lower-left cell
``(i, j)``. Its lens sits at the block centre with aperture ``size * d_min`` (the
diameter of a circle inscribed in the block, or the side of a square filling it), so
lenslets of disjoint blocks never overlap (they may touch). A block is *inside the
pupil* when its whole aperture lies within the pupil radius (the issue's
"inside the pupil" manufacturability constraint); cells whose own minimum lenslet is
outside are not lenslets at the start (:meth:`MLAPlane.initial_blocks`).

Focal lengths (documented rule)
-------------------------------
Algorithm 2 takes a focal-length list but its loop never chooses among it. Here a
lenslet's focal length depends only on the distance ``r`` of its centre from the axis:
``focal_lengths_mm[round(r / d_min) % n]`` (rings of width ``d_min`` cycle through the
list). With one focal length every lenslet keeps it (the camera stays at the lenslets'
focal plane whatever their aperture); with several (a multifocal XLFM) the assignment is
invariant under every symmetry below, so a symmetric layout stays symmetric in focus too.

Symmetry classes
----------------
``"none"``; ``"mirror"`` (x -> -x); ``"mirror-xy"`` (x -> -x and y -> -y, 4 elements);
``"4-fold"`` (rotations by 90 degrees); ``"8-fold"`` (rotations and mirrors, the square's
dihedral group). A merge under a symmetry merges the whole orbit of its block
(:func:`orbit`); the pupil and the cell grid are invariant under all of them.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from lfm_studio.engine.design import Design, DesignError, LensletSpec, MLASpec
from lfm_studio.engine.design.lenslet import LensletShape

SYMMETRIES = ("none", "mirror", "mirror-xy", "4-fold", "8-fold")
_SLACK_UM = 1e-6  # a lenslet touching the pupil rim (rounding) is inside


@dataclass(frozen=True, order=True)
class Block:
    """``size x size`` cells with lower-left cell ``(i, j)`` (``i`` along x, ``j`` along y)."""

    i: int
    j: int
    size: int

    def overlaps(self, other: Block) -> bool:
        """True when the two blocks share at least one cell."""
        return (
            self.i < other.i + other.size
            and other.i < self.i + self.size
            and self.j < other.j + other.size
            and other.j < self.j + self.size
        )

    def contains(self, other: Block) -> bool:
        """True when every cell of ``other`` is a cell of this block."""
        return (
            self.i <= other.i
            and other.i + other.size <= self.i + self.size
            and self.j <= other.j
            and other.j + other.size <= self.j + self.size
        )


def check_symmetry(symmetry: str) -> None:
    """Raise ``ValueError`` unless ``symmetry`` is one of :data:`SYMMETRIES`."""
    if symmetry not in SYMMETRIES:
        raise ValueError(
            f"symmetry must be one of {SYMMETRIES}; got {symmetry!r}. Fix: e.g. 'none' or '4-fold'."
        )


def _transforms(symmetry: str) -> tuple[tuple[int, int, int, int], ...]:
    """Group elements as integer matrices ``(a, b, c, d)``: ``(x, y) -> (a x + b y, c x + d y)``."""
    identity, mirror_x, mirror_y = (1, 0, 0, 1), (-1, 0, 0, 1), (1, 0, 0, -1)
    rotations = ((1, 0, 0, 1), (0, -1, 1, 0), (-1, 0, 0, -1), (0, 1, -1, 0))
    if symmetry == "none":
        return (identity,)
    if symmetry == "mirror":
        return (identity, mirror_x)
    if symmetry == "mirror-xy":
        return (identity, mirror_x, mirror_y, (-1, 0, 0, -1))
    if symmetry == "4-fold":
        return rotations
    diagonal = ((0, 1, 1, 0), (0, -1, -1, 0))
    return (*rotations, mirror_x, mirror_y, *diagonal)


def orbit(block: Block, cells: int, symmetry: str) -> tuple[Block, ...]:
    """The distinct images of ``block`` under ``symmetry`` on an ``cells x cells`` grid, sorted.

    Computed on doubled, centred coordinates so that every element maps cells to cells:
    the block's centre ``(2 i + size - cells, 2 j + size - cells)`` is transformed and the
    image block rebuilt around it.
    """
    check_symmetry(symmetry)
    cx, cy = 2 * block.i + block.size - cells, 2 * block.j + block.size - cells
    images = set()
    for a, b, c, d in _transforms(symmetry):
        x, y = a * cx + b * cy, c * cx + d * cy
        images.add(Block((x + cells - block.size) // 2, (y + cells - block.size) // 2, block.size))
    return tuple(sorted(images))


def merge(state: Sequence[Block], new: Sequence[Block]) -> tuple[tuple[Block, ...], str]:
    """Merge the blocks ``new`` into the layout ``state``; returns ``(blocks, reason)``.

    Every block of ``state`` lying wholly inside a new block is absorbed by it. The merge
    is refused (``reason`` says why, ``blocks`` is ``()``) when two new blocks overlap each
    other (a block crossing a symmetry axis onto its own image) or when a block of
    ``state`` overlaps a new block without lying inside it (a conflict: merged cells would
    belong to two lenslets). The result is sorted (one canonical order per layout).
    """
    new = tuple(sorted(set(new)))
    for k, a in enumerate(new):
        for b in new[k + 1 :]:
            if a.overlaps(b):
                return (), f"symmetry conflict: {a} overlaps its symmetric image {b}"
    kept = []
    for old in state:
        hits = [b for b in new if b.overlaps(old)]
        if not hits:
            kept.append(old)
        elif not any(b.contains(old) for b in hits):
            return (), f"conflict: {hits[0]} cuts through the existing lenslet {old}"
    return tuple(sorted((*kept, *new))), ""


@dataclass(frozen=True)
class MLAPlane:
    """The cell grid of one MLA plane, and how blocks become lenslets.

    Attributes
    ----------
    cell_um : float
        Cell side = minimum lenslet size ``d_min``, micrometres.
    cells : int
        ``M``, cells per side.
    pupil_diameter_um : float
        Diameter of the region lenslets must stay inside, micrometres.
    focal_lengths_mm : tuple of float
        Focal-length list (see the module docstring for the rule), millimetres.
    shape : "circle" or "square"
        Lenslet aperture shape: inscribed circle or the whole block.
    """

    cell_um: float
    cells: int
    pupil_diameter_um: float
    focal_lengths_mm: tuple[float, ...]
    shape: LensletShape = "circle"

    def __post_init__(self) -> None:
        if not (math.isfinite(self.cell_um) and self.cell_um > 0.0):
            raise ValueError(f"cell_um must be a finite number > 0 um; got {self.cell_um!r}. Fix: e.g. 1000.")
        if isinstance(self.cells, bool) or not isinstance(self.cells, int) or self.cells < 1:
            raise ValueError(f"cells must be an integer >= 1; got {self.cells!r}. Fix: a smaller cell_um.")
        if not (math.isfinite(self.pupil_diameter_um) and self.pupil_diameter_um > 0.0):
            raise ValueError(
                f"pupil_diameter_um must be a finite number > 0 um; got {self.pupil_diameter_um!r}. Fix: e.g. 16000."
            )
        if not self.focal_lengths_mm or any(
            not (math.isfinite(f) and f > 0.0) for f in self.focal_lengths_mm
        ):
            raise ValueError(
                f"focal_lengths_mm must hold focal lengths > 0 mm; got {self.focal_lengths_mm!r}. Fix: e.g. (26.0,)."
            )
        if self.shape not in ("circle", "square"):
            raise ValueError(f"shape must be 'circle' or 'square'; got {self.shape!r}.")

    @classmethod
    def from_design(
        cls,
        design: Design,
        min_lenslet_um: float,
        *,
        focal_lengths_mm: Sequence[float] | None = None,
        shape: LensletShape = "circle",
        plane_diameter_um: float | None = None,
    ) -> MLAPlane:
        """The plane of ``design`` cut into cells of ``min_lenslet_um`` micrometres.

        ``plane_diameter_um`` defaults to the pupil footprint on the MLA (Fourier kind);
        a conventional design has none, so it must be given. ``focal_lengths_mm``
        defaults to the design's distinct lenslet focal lengths.
        """
        if plane_diameter_um is None:
            pupil = design.pupil_diameter_at_mla
            if pupil is None:
                raise DesignError(
                    f"design kind {design.kind!r} has no pupil image on the MLA; plane_diameter_um is None. "
                    "Fix: pass plane_diameter_um (the MLA area to divide, in micrometres)."
                )
            plane_diameter_um = pupil / 1e-6
        if not (math.isfinite(min_lenslet_um) and 0.0 < min_lenslet_um <= plane_diameter_um):
            raise ValueError(
                f"min_lenslet_um must be > 0 and at most the plane diameter {plane_diameter_um:.6g} um; "
                f"got {min_lenslet_um!r}. Fix: e.g. {plane_diameter_um / 8:.6g} for 8 cells across."
            )
        cells = math.floor(plane_diameter_um / min_lenslet_um + 1e-9)
        focal = tuple(focal_lengths_mm) if focal_lengths_mm is not None else design.mla.focal_lengths_mm
        return cls(float(min_lenslet_um), cells, float(plane_diameter_um), tuple(map(float, focal)), shape)

    # ----- geometry of blocks -----

    def center_um(self, block: Block) -> tuple[float, float]:
        """Centre ``(x, y)`` of ``block`` on the MLA plane, micrometres from the axis."""
        half = self.cells / 2.0
        return (
            (block.i + block.size / 2.0 - half) * self.cell_um,
            (block.j + block.size / 2.0 - half) * self.cell_um,
        )

    def reach_um(self, block: Block) -> float:
        """Largest distance from the axis to the block's lenslet aperture, micrometres."""
        x, y = self.center_um(block)
        half = block.size * self.cell_um / 2.0
        if self.shape == "circle":
            return math.hypot(x, y) + half
        return math.hypot(abs(x) + half, abs(y) + half)

    def outside_reason(self, block: Block) -> str:
        """Why ``block`` is not a valid lenslet here ('' when it is)."""
        if block.size < 1 or block.i < 0 or block.j < 0 or max(block.i, block.j) + block.size > self.cells:
            return f"{block} is not on the {self.cells} x {self.cells} cell grid"
        reach, radius = self.reach_um(block), self.pupil_diameter_um / 2.0
        if reach > radius + _SLACK_UM:
            return f"{block} reaches {reach:.6g} um from the axis, beyond the pupil radius {radius:.6g} um"
        return ""

    def initial_blocks(self) -> tuple[Block, ...]:
        """All minimum lenslets inside the pupil (Algorithm 2, line 2), sorted."""
        every = (Block(i, j, 1) for i in range(self.cells) for j in range(self.cells))
        return tuple(b for b in every if not self.outside_reason(b))

    def focal_length_mm(self, block: Block) -> float:
        """Focal length of ``block``'s lenslet by the ring rule (module docstring), mm."""
        ring = round(math.hypot(*self.center_um(block)) / self.cell_um)
        return self.focal_lengths_mm[ring % len(self.focal_lengths_mm)]

    # ----- conversion to the design -----

    def lenslets(self, blocks: Iterable[Block]) -> tuple[LensletSpec, ...]:
        """The design lenslets of ``blocks`` (centres rounded to 1e-6 um, as design files keep them)."""
        out = []
        for block in blocks:
            x, y = self.center_um(block)
            out.append(
                LensletSpec(
                    center_um=(round(x, 6), round(y, 6)),
                    aperture_diameter_um=block.size * self.cell_um,
                    focal_length_mm=self.focal_length_mm(block),
                    shape=self.shape,
                )
            )
        return tuple(out)

    def design_with(self, design: Design, blocks: Sequence[Block]) -> Design:
        """``design`` with its MLA replaced by the lenslets of ``blocks`` (validated; may raise DesignError)."""
        if not blocks:
            raise DesignError(
                "blocks must hold at least one lenslet; got none. Fix: a larger pupil or smaller cells."
            )
        return design.updated(mla=MLASpec(lenslets=self.lenslets(blocks)))
