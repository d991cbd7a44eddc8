"""Microlens arrays: an explicit lenslet list, or a compact regular grid.

:class:`MLASpec` is the general form (any layout, per-lenslet focal length, shape
and aperture: what a Fourier LFM and the MLA editor use). :class:`RegularMLASpec`
describes a regular square or hexagonal array, or hexagonal rings around a central
lenslet (:data:`LATTICES`), by its pitch and size, so the
thousands of lenslets of a conventional LFM stay a few lines in a design file; its
``lenslets`` property expands it (lazily) into the same :class:`LensletSpec` tuple.
Both check at construction that every lenslet lies inside the optional array
aperture (a circle centred on the axis) and that no two apertures overlap
(touching is allowed).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import cached_property
from typing import Annotated, Any, Literal, get_args

from pydantic import Discriminator, Tag, model_validator

from lfm_studio.engine.design.base import SpecModel, si
from lfm_studio.engine.design.errors import DesignError, fmt, require_finite, require_positive
from lfm_studio.engine.design.geometry import candidate_pairs, list_pairs
from lfm_studio.engine.design.lenslet import LensletShape, LensletSpec, overlap_depth_um
from lfm_studio.engine.design.mla_builders import hex_grid, multifocal_hex, square_grid
from lfm_studio.engine.design.mla_layouts import hex_rect_sites, hex_ring_sites, square_sites

# Overlaps and rim excursions below this (micrometres) are rounding, not design: generated
# centres are rounded to 1e-6 um.
TOLERANCE_UM = 1e-5

Lattice = Literal["square", "hex", "rings"]
LATTICES: tuple[str, ...] = get_args(Lattice)
"""The lattices of a :class:`RegularMLASpec` (one source for checks, docs, spaces and front ends)."""


def check_lenslets(lenslets: Sequence[LensletSpec], array_aperture_diameter_um: float | None) -> None:
    """Raise :class:`DesignError` if a lenslet leaves the array aperture or two apertures overlap."""
    if array_aperture_diameter_um is not None:
        require_positive("array_aperture_diameter_um", array_aperture_diameter_um, "um", "or leave it out.")
        radius = array_aperture_diameter_um / 2.0
        outside = [
            f"{lens.describe(i)} reaches {fmt(lens.reach_um)} um"
            for i, lens in enumerate(lenslets)
            if lens.reach_um > radius + TOLERANCE_UM
        ]
        if outside:
            raise DesignError(
                f"lenslets must lie inside the array aperture of radius {fmt(radius)} um "
                f"(array_aperture_diameter_um {fmt(array_aperture_diameter_um)}): {list_pairs(outside)}. "
                "Fix: move or shrink those lenslets, or enlarge array_aperture_diameter_um."
            )
    # Two apertures can only overlap if, along each axis, their centres are closer than the larger size.
    reach = max(lens.aperture_diameter_um for lens in lenslets) + TOLERANCE_UM
    overlaps = []
    for i, j in candidate_pairs([lens.center_um for lens in lenslets], reach):
        depth = overlap_depth_um(lenslets[i], lenslets[j])
        if depth > TOLERANCE_UM:
            overlaps.append(
                f"{lenslets[i].describe(i)} and {lenslets[j].describe(j)} overlap by {fmt(depth)} um"
            )
    if overlaps:
        raise DesignError(
            f"lenslet apertures must not overlap: {list_pairs(overlaps)}. "
            "Fix: increase their spacing or reduce aperture_diameter_um (apertures may touch)."
        )


class _MLACommon:
    """What both MLA forms offer (``lenslets`` is a field of one and a property of the other).

    Deliberately without annotations: pydantic would turn them into fields.
    """

    @property
    def count(self) -> int:
        """Number of lenslets."""
        return len(self.lenslets)  # type: ignore[attr-defined]

    @property
    def array_aperture_diameter(self) -> float | None:
        """Array-aperture diameter in metres (None: unbounded)."""
        d = self.array_aperture_diameter_um  # type: ignore[attr-defined]
        return None if d is None else si(d, "um")

    @property
    def focal_lengths_mm(self) -> tuple[float, ...]:
        """Distinct lenslet focal lengths in mm, ascending (two or more: a multifocal array)."""
        return tuple(sorted({lens.focal_length_mm for lens in self.lenslets}))  # type: ignore[attr-defined]


class MLASpec(_MLACommon, SpecModel):
    """A microlens array as an explicit list of lenslets (any layout).

    Attributes
    ----------
    layout : "lenslets"
        Tag that tells the two MLA forms apart in a design file.
    lenslets : tuple of LensletSpec
        At least one; indices in messages refer to this order.
    array_aperture_diameter_um : float or None
        Diameter in micrometres of a circular array aperture centred on the axis.

    Build regular and multifocal layouts with :meth:`square_grid`, :meth:`hex_grid`
    and :meth:`multifocal_hex`.
    """

    layout: Literal["lenslets"] = "lenslets"
    lenslets: tuple[LensletSpec, ...]
    array_aperture_diameter_um: float | None = None

    @model_validator(mode="after")
    def _check(self) -> MLASpec:
        if not self.lenslets:
            raise DesignError("lenslets must hold at least one lenslet; got none. Fix: add lenslets.")
        check_lenslets(self.lenslets, self.array_aperture_diameter_um)
        return self

    square_grid = classmethod(square_grid)
    hex_grid = classmethod(hex_grid)
    multifocal_hex = classmethod(multifocal_hex)


class RegularMLASpec(_MLACommon, SpecModel):
    """A regular array of identical lenslets, stored by its pitch and size.

    Attributes
    ----------
    layout : "regular"
    lattice : "square", "hex" or "rings" (:data:`LATTICES`)
        Hexagonal arrays have rows along x, ``pitch sqrt(3)/2`` apart, alternate rows
        shifted by half a pitch (see :func:`~lfm_studio.engine.design.mla_layouts.hex_rect_sites`).
        ``"rings"``: a central lenslet on ``offset_um`` and ``r`` concentric hexagonal rings
        around it, ``1 + 3 r (r + 1)`` lenslets, six neighbours each at the pitch (see
        :func:`~lfm_studio.engine.design.mla_layouts.hex_ring_sites`).
    pitch_um : float
        Centre-to-centre spacing in micrometres.
    shape : (ny, nx)
        Rows and lenslets per row; the array is centred on ``offset_um``. For ``"rings"``
        it must be ``(2 r + 1, 2 r + 1)``: the rows of the hexagonal patch and the lenslets
        of its widest (central) row, so ``r = (ny - 1) / 2`` (:attr:`rings`).
    focal_length_mm : float
        Focal length of every lenslet, mm.
    lenslet_aperture_diameter_um : float or None
        Aperture diameter (or side) in micrometres; None means equal to the pitch.
    lenslet_shape : "circle" or "square"
    offset_um : (x, y)
        Shift of the array centre from the optical axis, micrometres.
    array_aperture_diameter_um : float or None
        As for :class:`MLASpec`.
    """

    layout: Literal["regular"] = "regular"
    lattice: Lattice = "square"
    pitch_um: float
    shape: tuple[int, int]
    focal_length_mm: float
    lenslet_aperture_diameter_um: float | None = None
    lenslet_shape: LensletShape = "circle"
    offset_um: tuple[float, float] = (0.0, 0.0)
    array_aperture_diameter_um: float | None = None

    @model_validator(mode="after")
    def _check(self) -> RegularMLASpec:
        require_positive("pitch_um", self.pitch_um, "um", "e.g. 150.")
        require_positive("focal_length_mm", self.focal_length_mm, "mm", "e.g. 3.")
        if self.shape[0] < 1 or self.shape[1] < 1:
            raise DesignError(f"shape must be (ny, nx) with both >= 1; got {self.shape}. Fix: e.g. (88, 88).")
        ny, nx = self.shape
        if self.lattice == "rings" and (ny != nx or ny % 2 == 0):
            r = max(0, (max(ny, nx) - 1) // 2)
            raise DesignError(
                f"shape must be (2 r + 1, 2 r + 1) for lattice 'rings' (r hexagonal rings around a central "
                f"lenslet: 2 r + 1 rows, 2 r + 1 lenslets in the central row, 1 + 3 r (r + 1) lenslets); got "
                f"{self.shape}. Fix: e.g. ({2 * r + 1}, {2 * r + 1}) for {r} ring(s), {1 + 3 * r * (r + 1)} lenslets."
            )
        if self.lenslet_aperture_diameter_um is not None:
            require_positive(
                "lenslet_aperture_diameter_um", self.lenslet_aperture_diameter_um, "um", "or leave it out."
            )
        require_finite("offset_um x", self.offset_um[0], "um", "e.g. 0.")
        require_finite("offset_um y", self.offset_um[1], "um", "e.g. 0.")
        # Every lenslet has the same neighbourhood: a 3 x 3 patch shows any overlap.
        check_lenslets(self._lenslets(limit=(3, 3)), None)
        if self.array_aperture_diameter_um is not None:
            check_lenslets(self.lenslets, self.array_aperture_diameter_um)
        return self

    @property
    def lenslet_aperture_um(self) -> float:
        """Aperture diameter (or side) of every lenslet, micrometres."""
        d = self.lenslet_aperture_diameter_um
        return self.pitch_um if d is None else d

    def centers_um(self, limit: tuple[int, int] | None = None) -> list[tuple[float, float]]:
        """Lenslet centres in micrometres, row by row (increasing y, then x).

        ``limit=(ry, rx)``: only the first ``ry`` rows and ``rx`` columns (a corner patch);
        for ``"rings"`` any limit gives the central lenslet and its first ring (the
        neighbourhood every lenslet has).
        """
        if self.lattice == "rings":
            rings = self.rings if limit is None else min(self.rings, 1)
            return hex_ring_sites(self.pitch_um, rings, self.offset_um)
        sites = square_sites if self.lattice == "square" else hex_rect_sites
        return sites(self.pitch_um, self.shape, self.offset_um, limit)

    @property
    def rings(self) -> int:
        """Rings around the central lenslet of a ``"rings"`` lattice, ``(ny - 1) // 2`` (0 for the others)."""
        return (self.shape[0] - 1) // 2 if self.lattice == "rings" else 0

    @property
    def count(self) -> int:
        """Number of lenslets (without building them): ``ny * nx``, or ``1 + 3 r (r + 1)`` for ``"rings"``."""
        if self.lattice == "rings":
            return 1 + 3 * self.rings * (self.rings + 1)
        return self.shape[0] * self.shape[1]

    def _lenslets(self, limit: tuple[int, int] | None = None) -> tuple[LensletSpec, ...]:
        # model_construct skips re-checking what this spec's own checks guarantee (finite
        # centres, positive aperture and focal length): about 10x faster for 10^4 lenslets.
        d, f, s = self.lenslet_aperture_um, self.focal_length_mm, self.lenslet_shape
        return tuple(
            LensletSpec.model_construct(center_um=c, aperture_diameter_um=d, focal_length_mm=f, shape=s)
            for c in self.centers_um(limit)
        )

    @cached_property
    def lenslets(self) -> tuple[LensletSpec, ...]:
        """All lenslets, row by row (built on first use, then cached)."""
        return self._lenslets()

    def to_explicit(self) -> MLASpec:
        """The same array as an editable :class:`MLASpec` lenslet list."""
        return MLASpec(lenslets=self.lenslets, array_aperture_diameter_um=self.array_aperture_diameter_um)


def _layout(value: Any) -> str | None:
    """The MLA form of ``value``: its ``layout`` key, else guessed (a ``pitch_um`` key means regular)."""
    if isinstance(value, dict):
        return value.get("layout", "regular" if "pitch_um" in value else "lenslets")
    return getattr(value, "layout", None)


AnyMLASpec = Annotated[
    Annotated[MLASpec, Tag("lenslets")] | Annotated[RegularMLASpec, Tag("regular")], Discriminator(_layout)
]
"""Either MLA form; the ``layout`` key ("lenslets" or "regular") picks one when reading a file."""
