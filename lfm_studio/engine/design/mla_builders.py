"""Helpers that build an :class:`~lfm_studio.engine.design.mla.MLASpec` from a regular
or multifocal layout (bound as its classmethods ``square_grid``, ``hex_grid`` and
``multifocal_hex``). Lengths in the units of the field names (um, mm).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

from lfm_studio.engine.design.errors import DesignError, fmt, require_positive
from lfm_studio.engine.design.lenslet import LensletShape, LensletSpec
from lfm_studio.engine.design.mla_layouts import (
    Point,
    hex_rect_sites,
    hex_ring_sites,
    hex_shells,
    square_sites,
)


def _build(
    cls: Any,
    centers: Sequence[Point],
    diameters_and_focals: Sequence[tuple[float, float]],
    shape: LensletShape,
    keep_within_diameter_um: float | None,
    array_aperture_diameter_um: float | None,
) -> Any:
    lenslets = [
        LensletSpec(center_um=c, aperture_diameter_um=d, focal_length_mm=f, shape=shape)
        for c, (d, f) in zip(centers, diameters_and_focals, strict=True)
    ]
    if keep_within_diameter_um is not None:
        require_positive(
            "keep_within_diameter_um", keep_within_diameter_um, "um", "e.g. the pupil diameter at the MLA."
        )
        lenslets = [lens for lens in lenslets if lens.reach_um <= keep_within_diameter_um / 2.0 + 1e-5]
        if not lenslets:
            raise DesignError(
                f"no lenslet fits inside keep_within_diameter_um {fmt(keep_within_diameter_um)} um. "
                "Fix: enlarge it, or reduce the pitch or fill_factor."
            )
    return cls(lenslets=tuple(lenslets), array_aperture_diameter_um=array_aperture_diameter_um)


def _pair(shape: int | tuple[int, int]) -> tuple[int, int]:
    ny, nx = (shape, shape) if isinstance(shape, int) else shape
    if ny < 1 or nx < 1:
        raise DesignError(
            f"shape must be a count >= 1 or (ny, nx) with both >= 1; got {shape!r}. Fix: e.g. 5."
        )
    return (ny, nx)


def _fill(pitch_um: float, fill_factor: float) -> float:
    require_positive("pitch_um", pitch_um, "um", "e.g. 150.")
    require_positive("fill_factor", fill_factor, "", "aperture diameter = fill_factor * pitch_um, e.g. 1.0.")
    return fill_factor * pitch_um


def square_grid(
    cls: Any,
    pitch_um: float,
    shape: int | tuple[int, int],
    focal_length_mm: float,
    *,
    fill_factor: float = 1.0,
    lenslet_shape: LensletShape = "circle",
    offset_um: Point = (0.0, 0.0),
    keep_within_diameter_um: float | None = None,
    array_aperture_diameter_um: float | None = None,
) -> Any:
    """Square lattice of identical lenslets, centred on ``offset_um``.

    Parameters
    ----------
    pitch_um : centre-to-centre spacing, micrometres.
    shape : ``n`` for ``n x n`` or ``(ny, nx)``; a lenslet sits on the centre when the count is odd.
    focal_length_mm : focal length of every lenslet, mm.
    fill_factor : aperture diameter (or side) as a fraction of the pitch.
    lenslet_shape : "circle" or "square".
    offset_um : (x, y) shift of the lattice, micrometres.
    keep_within_diameter_um : keep only lenslets entirely inside a centred circle of this
        diameter (e.g. the pupil image at the MLA of a Fourier LFM).
    array_aperture_diameter_um : stored as the array aperture.
    """
    d = _fill(pitch_um, fill_factor)
    centers = square_sites(pitch_um, _pair(shape), offset_um)
    return _build(
        cls,
        centers,
        [(d, focal_length_mm)] * len(centers),
        lenslet_shape,
        keep_within_diameter_um,
        array_aperture_diameter_um,
    )


def hex_grid(
    cls: Any,
    pitch_um: float,
    focal_length_mm: float,
    *,
    rings: int | None = None,
    shape: tuple[int, int] | None = None,
    fill_factor: float = 1.0,
    lenslet_shape: LensletShape = "circle",
    offset_um: Point = (0.0, 0.0),
    keep_within_diameter_um: float | None = None,
    array_aperture_diameter_um: float | None = None,
) -> Any:
    """Hexagonal lattice of identical lenslets: ``rings`` around a central lenslet, or ``shape`` rows.

    ``rings=r`` gives ``1 + 3 r (r + 1)`` lenslets, six neighbours each at ``pitch_um``;
    ``shape=(ny, nx)`` gives ``ny`` rows of ``nx`` (alternate rows shifted by half a pitch).
    Other parameters as :func:`square_grid`.
    """
    if (rings is None) == (shape is None):
        raise DesignError(
            f"give exactly one of rings or shape; got rings={rings!r}, shape={shape!r}. Fix: e.g. rings=2."
        )
    d = _fill(pitch_um, fill_factor)
    if rings is not None:
        centers = hex_ring_sites(pitch_um, rings, offset_um)
    else:
        centers = hex_rect_sites(pitch_um, _pair(shape), offset_um)  # type: ignore[arg-type]
    return _build(
        cls,
        centers,
        [(d, focal_length_mm)] * len(centers),
        lenslet_shape,
        keep_within_diameter_um,
        array_aperture_diameter_um,
    )


def multifocal_hex(
    cls: Any,
    pitch_um: float,
    count: int,
    focal_lengths_mm: Sequence[float],
    *,
    aperture_diameter_um: float,
    center: Literal["lenslet", "triangle"] = "lenslet",
    lenslet_shape: LensletShape = "circle",
    array_aperture_diameter_um: float | None = None,
) -> Any:
    """XLFM-like multifocal array: the ``count`` hexagonal sites nearest the axis, in focal groups.

    Sites come in shells of equal radius (see :func:`~lfm_studio.engine.design.mla_layouts.hex_shells`);
    within each shell, going round in angle, lenslets take the focal lengths of
    ``focal_lengths_mm`` in turn, so every group samples the whole pupil (as the two
    interleaved groups of Cong et al. 2017). Lenslets are ordered shell by shell.

    Parameters
    ----------
    pitch_um : lattice spacing, micrometres (may exceed the aperture: apertures need not touch).
    count : number of lenslets; must complete a shell (the error lists valid counts).
    focal_lengths_mm : one focal length per group, mm (e.g. ``(26.0, 28.5)``).
    aperture_diameter_um : aperture diameter (or side) of every lenslet, micrometres.
    center : ``"lenslet"`` (a lenslet on the axis) or ``"triangle"`` (axis between three lenslets).
    """
    require_positive("pitch_um", pitch_um, "um", "e.g. 2200.")
    if not focal_lengths_mm:
        raise DesignError(
            "focal_lengths_mm must list at least one focal length (mm); got none. Fix: e.g. (26.0, 28.5)."
        )
    centers, pairs = [], []
    for shell in hex_shells(pitch_um, count, center):
        for k, point in enumerate(shell):
            centers.append(point)
            pairs.append((aperture_diameter_um, focal_lengths_mm[k % len(focal_lengths_mm)]))
    return _build(cls, centers, pairs, lenslet_shape, None, array_aperture_diameter_um)
