"""Cell-like blobs filling an ellipsoid, by default a larval zebrafish brain.

The larval zebrafish brain is about 400 x 800 x 250 um (x by y by z) and its
neuron bodies are 3-7 um across (thesis section 2, citing [19]); the defaults follow.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.phantoms.phantom import (
    Phantom,
    centre_index,
    check_count,
    check_dtype,
    check_shape,
    check_triple,
    make_generator,
)
from lfm_studio.engine.phantoms.placement import place_separated
from lfm_studio.engine.phantoms.stamping import nearest_voxel, stamp_ellipsoids
from lfm_studio.engine.units import um

#: Semi-axes (z, y, x) in metres of a larval zebrafish brain, 250 x 800 x 400 um overall.
ZEBRAFISH_BRAIN_SEMI_AXES: tuple[float, float, float] = (125 * um, 400 * um, 200 * um)
#: Default cells per cubic metre: 1e-3 per um^3, about 42,000 cells in the default brain,
#: filling about 12 % of it (a real larval brain holds of order 1e5 neurons; sparser
#: defaults keep cells resolvable and placement fast).
DEFAULT_CELL_DENSITY: float = 1e-3 / um**3


def cells_in_ellipsoid(
    shape: tuple[int, int, int] | None = None,
    *,
    voxel_size: tuple[float, float, float],
    seed: int | torch.Generator,
    semi_axes: tuple[float, float, float] = ZEBRAFISH_BRAIN_SEMI_AXES,
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0),
    cell_semi_axes: tuple[float, float, float] = (3 * um, 3 * um, 3 * um),
    count: int | None = None,
    density: float | None = None,
    size_spread: float = 0.2,
    brightness: tuple[float, float] = (0.5, 1.0),
    separation: float = 1.0,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> Phantom:
    """Non-overlapping ellipsoidal cells at random inside an ellipsoid.

    Parameters
    ----------
    shape : (Z, Y, X), optional
        Volume size in voxels; default: just enough to hold the ellipsoid (odd sizes, so
        the origin is the centre voxel). A smaller shape crops the ellipsoid.
    voxel_size : (dz, dy, dx)
        Voxel size in metres.
    seed : int or CPU ``torch.Generator``
        Same seed, same cells (on every device).
    semi_axes : (z, y, x)
        Semi-axes of the outline ellipsoid in metres (default: larval zebrafish brain).
    centre : (z, y, x)
        Ellipsoid centre in metres (origin = voxel ``N // 2`` of each axis).
    cell_semi_axes : (z, y, x)
        Mean cell semi-axes in metres (default 3 um radius; e.g. ``(2.5*um, 1.5*um, 1.5*um)``
        for 3 x 3 x 5 um cells).
    count, density : int or float, at most one
        Number of cells, or cells per cubic metre of the ellipsoid part inside the
        volume (e.g. ``1e-3 / um**3``); default :data:`DEFAULT_CELL_DENSITY`.
    size_spread : float in [0, 0.5]
        Each cell is scaled by a factor uniform in ``[1 - size_spread, 1 + size_spread]``.
    brightness : (low, high)
        Cell values are uniform in ``[low, high]``.
    separation : float
        Minimum distance between two cells' centres as a multiple of the distance at which
        they touch; 1 (default): cells may touch but never overlap; below 1 they may
        overlap (overlaps keep the brighter value). Random packing slows down and then
        stalls as the cells (scaled by ``separation``) approach about 30 % of the ellipsoid:
        2.4e-3 cells per um^3 (about 100,000 default cells in the brain) still places,
        3e-3 raises :class:`PlacementError` naming how many fitted.
        Cell centres keep the largest cell semi-axes away from the outline; a ``shape``
        smaller than the ellipsoid cuts cells at the volume border, like a crop.
    dtype, device : of the volume.

    Returns
    -------
    Phantom
        ``data`` ``(Z, Y, X)`` (zero outside the ellipsoid), cell ``positions``, ``semi_axes``
        and ``intensities``.
    """
    check_dtype(dtype)
    d = check_triple("voxel_size", voxel_size, hint="give (dz, dy, dx) in metres, e.g. (2 * um,) * 3.")
    axes = check_triple("semi_axes", semi_axes, hint="give the ellipsoid semi-axes (z, y, x) in metres.")
    cell = check_triple(
        "cell_semi_axes", cell_semi_axes, hint="give cell semi-axes in metres, e.g. (3 * um,) * 3."
    )
    origin = tuple(float(c) for c in centre)
    if len(origin) != 3 or not all(math.isfinite(c) for c in origin):
        raise ValueError(f"centre must be three finite lengths (z, y, x) in metres; got {centre!r}.")
    shape = check_shape(
        shape
        if shape is not None
        else tuple(2 * math.ceil((abs(c) + a) / s) + 3 for c, a, s in zip(origin, axes, d, strict=True))
    )
    if not (0 <= size_spread <= 0.5):
        raise ValueError(f"size_spread must be in [0, 0.5]; got {size_spread!r}.")
    low, high = (float(b) for b in brightness)
    if not (math.isfinite(low) and math.isfinite(high) and 0 <= low <= high and high > 0):
        raise ValueError(
            f"brightness must be (low, high) with 0 <= low <= high, high > 0; got {brightness!r}."
        )
    if not (math.isfinite(separation) and separation > 0):
        raise ValueError(f"separation must be a finite number > 0; got {separation!r}.")

    spacing = torch.tensor(d, dtype=torch.float64)
    a = torch.tensor(axes, dtype=torch.float64)
    c0 = torch.tensor(origin, dtype=torch.float64)
    idx_centre = centre_index(shape)
    volume_inside = _voxels_inside(shape, spacing, a, c0) * math.prod(d)
    if count is not None and density is not None:
        raise ValueError("give count or density, not both.")
    if count is None:
        density = DEFAULT_CELL_DENSITY if density is None else float(density)
        if not (math.isfinite(density) and density >= 0):
            raise ValueError(f"density must be a finite number >= 0 per m^3; got {density!r}.")
        count = round(density * volume_inside)
    count = check_count(count)

    largest = torch.tensor(cell, dtype=torch.float64) * (1 + size_spread)
    inner = a - largest  # centres here keep most of each cell inside the outline
    box_lo = torch.maximum((0 - idx_centre) * spacing, c0 - inner)
    box_hi = torch.minimum((torch.tensor(shape) - 1 - idx_centre) * spacing, c0 + inner)
    if count > 0 and (bool((inner <= 0).any()) or bool((box_lo > box_hi).any())):
        raise ValueError(
            f"cells of semi-axes {tuple(float(v) / um for v in largest)} um (with size_spread) do not fit in "
            f"the ellipsoid {tuple(v / um for v in axes)} um inside a volume of {shape} voxels. "
            "Fix: smaller cells, a larger ellipsoid or a larger shape."
        )
    generator = make_generator(seed)

    def sample(k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Centres uniform in the inner ellipsoid (and the volume), and relative sizes."""
        u = torch.rand((2 * k + 16, 4), generator=generator, dtype=torch.float64) * 2 - 1
        p = c0 + u[:, :3] * inner
        keep = ((u[:, :3] ** 2).sum(-1) <= 1) & ((p >= box_lo) & (p <= box_hi)).all(-1)
        factor = 1 + size_spread * u[keep, 3]
        return p[keep][:k], (factor / (1 + size_spread))[:k]

    positions, sizes = place_separated(
        count,
        sample,
        low=box_lo,
        high=box_hi,
        scale=2 * largest * separation,
        min_size=(1 - size_spread) / (1 + size_spread),
    )
    cells = (sizes * (1 + size_spread))[:, None] * torch.tensor(cell, dtype=torch.float64)
    values = low + (high - low) * torch.rand(count, generator=generator, dtype=torch.float64)

    data = stamp_ellipsoids(shape, d, positions, cells, values, dtype=dtype, device=device, clip=(c0, a))
    return Phantom(data, d, positions, nearest_voxel(positions, shape, spacing), cells, values)


def _voxels_inside(
    shape: tuple[int, int, int], spacing: torch.Tensor, a: torch.Tensor, c0: torch.Tensor
) -> int:
    """Number of voxel centres inside the ellipsoid, counted row by row (O(Z Y), exact)."""
    centre = centre_index(shape)
    z = (torch.arange(shape[0], dtype=torch.float64) - centre[0]) * spacing[0] - c0[0]
    y = (torch.arange(shape[1], dtype=torch.float64) - centre[1]) * spacing[1] - c0[1]
    rest = 1 - (z[:, None] / a[0]) ** 2 - (y[None, :] / a[1]) ** 2
    half = a[2] * rest.clamp_min(0).sqrt()  # x half-width of each (z, y) row, metres
    # Indices i with |(i - cx) * dx - x0| <= half, clipped to [0, X - 1].
    lo = torch.ceil((c0[2] - half) / spacing[2] + centre[2]).clamp(0, shape[2])
    hi = torch.floor((c0[2] + half) / spacing[2] + centre[2]).clamp(-1, shape[2] - 1)
    return int(((hi - lo + 1).clamp_min(0) * (rest >= 0)).sum())
