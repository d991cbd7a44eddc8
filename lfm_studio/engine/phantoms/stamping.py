"""Draw many small objects into a volume by stamping patches, never looping over the volume.

Each object touches only a small patch of voxels around its centre. All patches of
a chunk of objects are evaluated at once, separably per axis (``(objects, Pz, Py, Px)``
broadcasts), and written with one ``scatter_reduce(amax)``, so overlapping objects
take the larger value instead of adding up. Cost grows with objects x patch size,
not with the volume.
"""

from __future__ import annotations

import math

import torch

_PATCH_ELEMENTS = 1 << 22  # objects x patch voxels per chunk (tens of MB of float32 work)


def nearest_voxel(
    positions: torch.Tensor, shape: tuple[int, int, int], voxel_size: torch.Tensor
) -> torch.Tensor:
    """Index ``(N, 3)`` int64 of the voxel nearest to each centre (metres, centred convention)."""
    centre = torch.tensor([n // 2 for n in shape], dtype=torch.float64)
    return torch.floor(positions / voxel_size + centre + 0.5).to(torch.int64)


def stamp_points(
    shape: tuple[int, int, int], indices: torch.Tensor, values: torch.Tensor, *, dtype, device
) -> torch.Tensor:
    """Volume with ``values[n]`` at voxel ``indices[n]`` (coinciding points keep the maximum)."""
    out = torch.zeros(shape, dtype=dtype, device=device)
    strides = torch.tensor([shape[1] * shape[2], shape[2], 1], dtype=torch.int64)
    flat = (indices * strides).sum(-1).to(device)
    out.view(-1).scatter_reduce_(0, flat, values.to(device=device, dtype=dtype), reduce="amax")
    return out


def stamp_ellipsoids(
    shape: tuple[int, int, int],
    voxel_size: tuple[float, float, float],
    positions: torch.Tensor,
    semi_axes: torch.Tensor,
    values: torch.Tensor,
    *,
    dtype: torch.dtype,
    device: torch.device | str | None,
    clip: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> torch.Tensor:
    """Volume ``(Z, Y, X)`` holding axis-aligned ellipsoids with partial-volume edges.

    Parameters
    ----------
    voxel_size : (dz, dy, dx) metres.
    positions, semi_axes : ``(N, 3)`` float64, metres (semi-axes > 0).
    values : ``(N,)`` value inside each ellipsoid.
    clip : optional ``(centre, semi_axes)`` ``(3,)`` metres of an outline ellipsoid; voxels
        whose centre lies outside it stay empty (keeps cells inside a brain).

    Notes
    -----
    A voxel at distance ``rho`` from a centre, in direction ``u``, gets the fraction
    ``clamp(1/2 - (rho - r') / w, 0, 1)``: a linear ramp across the surface, as wide as the
    voxel along ``u`` (``w = sum_i |u_i| d_i``). Along each ray the ramp is centred at
    ``r'`` solving ``r'^3 + r' w^2 / 4 = r(u)^3`` (``r(u) = 1 / |u / a|``, the ellipsoid
    radius), which makes the ramp's integral equal to the ellipsoid volume; the sum
    over voxels is then the volume up to lattice (aliasing) error, zero on average
    over sub-voxel positions.
    """
    out = torch.zeros(shape, dtype=dtype, device=device)
    if positions.shape[0] == 0:
        return out
    unit = min(voxel_size)  # work in units of the smallest voxel side, float32 is then ample
    work = torch.float64 if dtype == torch.float64 else torch.float32
    d = torch.tensor(voxel_size, dtype=torch.float64) / unit
    centre = torch.tensor([n // 2 for n in shape], dtype=torch.float64)
    # Reach of the ramp along axis i is at most a_i + d_i / 2 + sum_{j != i} d_j / 4.
    a_max = semi_axes.max(dim=0).values / unit
    half = [math.ceil(float(r)) for r in (a_max + d / 2 + (d.sum() - d) / 4) / d]
    patch = math.prod(2 * k + 1 for k in half)
    chunk = max(1, _PATCH_ELEMENTS // patch)
    strides = (shape[1] * shape[2], shape[2], 1)
    flat_out = out.view(-1)
    for start in range(0, positions.shape[0], chunk):
        fractional = positions[start : start + chunk] / unit / d + centre  # (n, 3) voxel index
        base = torch.floor(fractional + 0.5).to(torch.int64)
        axes = (semi_axes[start : start + chunk] / unit).to(device=device, dtype=work)
        val = values[start : start + chunk].to(device=device, dtype=work)
        n = fractional.shape[0]
        # Sums over the three axes, broadcast up from 0-d starts to (n, 2kz+1, 2ky+1, 2kx+1).
        zero = torch.zeros((), device=device, dtype=work)
        sq, sq_scaled, proj, clip_sq = zero, zero, zero, zero
        flat = torch.zeros((), device=device, dtype=torch.int64)
        valid = torch.ones((), device=device, dtype=torch.bool)
        for i, k in enumerate(half):
            view = [n, 1, 1, 1]
            view[i + 1] = 2 * k + 1
            index = base[:, i : i + 1] + torch.arange(-k, k + 1)  # (n, 2k+1) int64
            delta = ((index - fractional[:, i : i + 1]) * d[i]).to(device=device, dtype=work)
            index = index.to(device)
            sq = sq + (delta**2).view(view)
            sq_scaled = sq_scaled + ((delta / axes[:, i : i + 1]) ** 2).view(view)
            proj = proj + (delta.abs() * float(d[i])).view(view)
            flat = flat + (index * strides[i]).view(view)
            valid = valid & ((index >= 0) & (index < shape[i])).view(view)
            if clip is not None:
                c, a = (float(clip[0][i]) / unit, float(clip[1][i]) / unit)
                where = ((index - float(centre[i])).to(work) * float(d[i]) - c) / a
                clip_sq = clip_sq + (where**2).view(view)
        rho = sq.sqrt()
        # Ellipsoid radius along the ray; the centre voxel (rho = 0) gets a huge radius: fully inside.
        ray = torch.where(sq_scaled > 0, rho / sq_scaled.clamp_min(1e-30).sqrt(), 1e6)
        width = (proj / rho.clamp_min(1e-12)).clamp_min(float(d.min()))
        ray_c, cube, w2 = ray, ray**3, width**2 / 4
        for _ in range(2):  # Newton on r'^3 + r' w^2/4 = r^3 from r' = r (converges from above)
            ray_c = ray_c - (ray_c**3 + ray_c * w2 - cube) / (3 * ray_c**2 + w2)
        fraction = (0.5 - (rho - ray_c) / width).clamp(0.0, 1.0) * val.view(n, 1, 1, 1)
        keep = valid & (fraction > 0)
        if clip is not None:
            keep = keep & (clip_sq <= 1)
        keep = keep.expand_as(fraction)
        flat_out.scatter_reduce_(0, flat.expand_as(fraction)[keep], fraction[keep].to(dtype), reduce="amax")
    return out
