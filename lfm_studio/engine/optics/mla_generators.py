"""Regular microlens arrays: square and hexagonal lattices as :class:`MicrolensArray`.

Both generators return the same validated object as an arbitrary layout. Either a
lattice size is given (``count`` for square, ``rings`` for hexagonal) or a region
(``extent`` rectangle and/or circular ``aperture_diameter``, centred on the axis),
in which case every lattice site whose aperture fits entirely inside is kept.
Lenslets are ordered row by row (increasing y), then by increasing x.
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.errors import require_finite, require_positive
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray, outside_reason

Scalar = float | torch.Tensor


def _check_common(pitch: float, aperture_fraction: float, offset: tuple[float, float]) -> None:
    require_positive("pitch", pitch, "m", "give the lenslet spacing in metres, e.g. 150 * um.")
    require_positive(
        "aperture_fraction", aperture_fraction, "", "aperture diameter = aperture_fraction * pitch, e.g. 1.0."
    )
    require_finite("offset x", offset[0], "m")
    require_finite("offset y", offset[1], "m")


def _region(
    extent: tuple[float, float] | float | None, aperture_diameter: float | None
) -> tuple[float, float]:
    """Half sizes (x, y) in metres of the box that bounds the requested region."""
    half_x = half_y = math.inf
    if extent is not None:
        width, height = (extent, extent) if isinstance(extent, (int, float)) else extent
        half_x, half_y = width / 2.0, height / 2.0
    if aperture_diameter is not None:
        half_x, half_y = min(half_x, aperture_diameter / 2.0), min(half_y, aperture_diameter / 2.0)
    return half_x, half_y


def _build(
    centers: list[tuple[float, float]],
    diameter: float,
    focal_length: Scalar,
    shape: str,
    extent: tuple[float, float] | float | None,
    aperture_diameter: float | None,
) -> MicrolensArray:
    if isinstance(extent, (int, float)):
        extent = (float(extent), float(extent))
    lenslets = [Lenslet(c, diameter, focal_length, shape) for c in centers]
    if extent is not None or aperture_diameter is not None:
        lenslets = [lens for lens in lenslets if not outside_reason(lens, aperture_diameter, extent)]
        if not lenslets:
            raise ValueError(
                f"no lenslet of diameter {diameter / 1e-6:.6g} um fits in the region "
                f"(extent {extent} m, aperture_diameter {aperture_diameter} m). "
                "Fix: enlarge the region or reduce pitch / aperture_fraction."
            )
    return MicrolensArray(tuple(lenslets), aperture_diameter=aperture_diameter, extent=extent)


def _one_of(size: object, size_name: str, extent: object, aperture_diameter: object) -> None:
    region = extent is not None or aperture_diameter is not None
    if (size is None) == (not region):
        raise ValueError(
            f"give either {size_name} or a region (extent and/or aperture_diameter), not both or neither; "
            f"got {size_name}={size!r}, extent={extent!r}, aperture_diameter={aperture_diameter!r}."
        )


def square_grid(
    pitch: float,
    focal_length: Scalar,
    *,
    count: int | tuple[int, int] | None = None,
    extent: tuple[float, float] | float | None = None,
    aperture_diameter: float | None = None,
    aperture_fraction: float = 1.0,
    shape: str = "circle",
    offset: tuple[float, float] = (0.0, 0.0),
) -> MicrolensArray:
    """Square lattice of identical lenslets.

    Parameters
    ----------
    pitch : float
        Centre-to-centre spacing in metres.
    focal_length : float or 0-d tensor
        Focal length in metres, shared by all lenslets.
    count : int or (ny, nx), optional
        Lattice size; the lattice is centred on ``offset`` (a lenslet sits on it when
        the count is odd).
    extent : float or (width, height), optional
        Rectangular region in metres, centred on the axis; lattice sites
        ``offset + (i, j) * pitch`` whose aperture fits inside are kept.
    aperture_diameter : float, optional
        Circular region (array aperture) diameter in metres, centred on the axis.
    aperture_fraction : float
        Lenslet aperture diameter (or side) as a fraction of the pitch.
    shape : "circle" or "square"
    offset : (x, y)
        Shift of the lattice in metres.
    """
    _check_common(pitch, aperture_fraction, offset)
    _one_of(count, "count", extent, aperture_diameter)
    ox, oy = float(offset[0]), float(offset[1])
    if count is not None:
        ny, nx = (count, count) if isinstance(count, int) else count
        if ny < 1 or nx < 1:
            raise ValueError(f"count must be positive; got {count!r}.")
        iy, ix = [i - (ny - 1) / 2.0 for i in range(ny)], [j - (nx - 1) / 2.0 for j in range(nx)]
    else:
        half_x, half_y = _region(extent, aperture_diameter)
        ix = list(range(math.floor((-half_x - ox) / pitch), math.ceil((half_x - ox) / pitch) + 1))
        iy = list(range(math.floor((-half_y - oy) / pitch), math.ceil((half_y - oy) / pitch) + 1))
    centers = [(ox + j * pitch, oy + i * pitch) for i in iy for j in ix]
    return _build(centers, aperture_fraction * pitch, focal_length, shape, extent, aperture_diameter)


def hex_grid(
    pitch: float,
    focal_length: Scalar,
    *,
    rings: int | None = None,
    extent: tuple[float, float] | float | None = None,
    aperture_diameter: float | None = None,
    aperture_fraction: float = 1.0,
    shape: str = "circle",
    offset: tuple[float, float] = (0.0, 0.0),
) -> MicrolensArray:
    """Hexagonal lattice of identical lenslets (rows along x, row spacing ``pitch * sqrt(3) / 2``).

    Parameters as :func:`square_grid`, except ``rings``: the number of hexagonal
    rings around the central lenslet at ``offset``, giving ``1 + 3 rings (rings + 1)``
    lenslets. Site ``(q, r)`` sits at ``offset + pitch * (q + r / 2, r sqrt(3) / 2)``;
    every lenslet has six neighbours at distance ``pitch``.
    """
    _check_common(pitch, aperture_fraction, offset)
    _one_of(rings, "rings", extent, aperture_diameter)
    ox, oy = float(offset[0]), float(offset[1])
    row = pitch * math.sqrt(3.0) / 2.0
    if rings is not None:
        if isinstance(rings, bool) or not isinstance(rings, int) or rings < 0:
            raise ValueError(f"rings must be an integer >= 0; got {rings!r}.")
        sites = [
            (q, r)
            for r in range(-rings, rings + 1)
            for q in range(-rings, rings + 1)
            if max(abs(q), abs(r), abs(q + r)) <= rings
        ]
    else:
        half_x, half_y = _region(extent, aperture_diameter)
        r_range = range(math.floor((-half_y - oy) / row), math.ceil((half_y - oy) / row) + 1)
        sites = []
        for r in r_range:
            shift = ox + r * pitch / 2.0
            q_range = range(math.floor((-half_x - shift) / pitch), math.ceil((half_x - shift) / pitch) + 1)
            sites.extend((q, r) for q in q_range)
    centers = [(ox + pitch * (q + r / 2.0), oy + row * r) for q, r in sites]
    return _build(centers, aperture_fraction * pitch, focal_length, shape, extent, aperture_diameter)
