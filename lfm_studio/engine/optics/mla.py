"""Microlens-array transmission (thesis Algorithm 1) and its application to a field.

Each lenslet ``i`` is a thin lens (eq. 3.15) with its own pupil:
``t(x, y) = P_i(x - cx_i, y - cy_i) exp(-j k ((x - cx_i)^2 + (y - cy_i)^2) / (2 f_i))``
inside its aperture, and the array transmits nothing between apertures.

How Algorithm 1 is carried out here
-----------------------------------
Algorithm 1 precomputes one thin-lens patch per focal length and pastes it at each
lenslet's pixel. That is exact only when centres fall on pixel centres. Here each
lenslet is placed at its *nearest* pixel and the patch is evaluated around the *true*
centre, i.e. at coordinates ``(x_p - dx_i, y_p - dy_i)`` where ``(x_p, y_p)`` are the
patch pixel offsets and ``(dx_i, dy_i)`` is the sub-pixel remainder (|d| <= half a
pixel): phase and pupil both follow the true centre. Lenslets are grouped by
(shape, patch size in pixels); per group the patch coordinates are built once and
one patch is evaluated per distinct (focal length, aperture, sub-pixel offset
rounded to 1e-6 pixel). For a regular array whose pitch is a whole number of pixels
that is a single patch, exactly Algorithm 1's dictionary. The rounding moves a
lenslet by at most 1e-6 pixel (phase error below ``pi * 1e-6`` rad at the Nyquist
limit). Patches are then scattered into the grid: the cost is O(total lenslet
pixels) plus allocating the output, never O(lenslets x grid). Parts of lenslets
outside the grid are cropped.

Differentiability: with respect to the field and to the focal lengths (tensor
``Lenslet.focal_length`` entries or the ``focal_lengths`` override, e.g. an
``nn.Parameter`` of shape ``(L,)``); then every lenslet gets its own patch.
Centres and diameters are geometry (floats); their placement is discrete.
"""

from __future__ import annotations

import math
from collections import defaultdict

import torch

from lfm_studio.engine.errors import require_finite_tensor, require_positive
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.mla_layout import MicrolensArray
from lfm_studio.engine.optics.pupils import disk_coverage, square_coverage
from lfm_studio.engine.optics.sampling import check_quadratic_phase_sampling

Device = torch.device | str | None
_OFFSET_RESOLUTION = 1e-6  # pixels; sub-pixel offsets closer than this share a patch


def _focal_lengths(mla: MicrolensArray, override: torch.Tensor | None, device: torch.device) -> torch.Tensor:
    if override is None:
        f = mla.focal_lengths(device)
    else:
        if not isinstance(override, torch.Tensor) or override.shape != (len(mla),) or override.is_complex():
            raise ValueError(
                f"focal_lengths must be a real tensor of shape ({len(mla)},) (one per lenslet); "
                f"got {getattr(override, 'shape', type(override).__name__)}. Fix: torch.full(({len(mla)},), f)."
            )
        require_finite_tensor("focal_lengths", override.detach())
        f = override
    bad = torch.nonzero(f.detach() <= 0.0).flatten()
    if bad.numel():
        i = int(bad[0])
        raise ValueError(
            f"focal length of lenslet {i} must be > 0 m; got {float(f.detach()[i]):.6g} m. Fix: use converging lenslets."
        )
    return f.to(device=device, dtype=torch.float64)


def _patch_half_size(half_width: float, pitch: float) -> int:
    """Patch half-size in pixels covering the aperture around any sub-pixel centre.

    Coverage is non-zero up to ``half_width + 0.71 pitch`` from the true centre (edge
    pixel projection), which is at most half a pixel from the patch centre.
    """
    return math.ceil(half_width / pitch + 1.5)


def mla_transmission(
    mla: MicrolensArray,
    grid: Grid,
    wavelength: float,
    *,
    refractive_index: float = 1.0,
    focal_lengths: torch.Tensor | None = None,
    antialias: bool = False,
    dtype: torch.dtype = torch.complex64,
    device: Device = None,
) -> torch.Tensor:
    """Complex transmission ``(ny, nx)`` of ``mla`` on ``grid`` (zero outside the lenslets).

    Parameters
    ----------
    mla : MicrolensArray
    grid : Grid
        Sampling of the MLA plane (the lenslet centres are relative to its axis).
    wavelength : float
        Vacuum wavelength in metres.
    refractive_index : float
        Index of the medium behind the array (``k = 2 pi n / lambda``).
    focal_lengths : tensor ``(L,)``, optional
        Per-lenslet focal lengths in metres overriding those of the lenslets.
    antialias : bool
        Area-coverage aperture edges (see :mod:`pupils`).
    dtype, device : complex dtype and device of the result.

    Warns
    -----
    SamplingWarning
        When a lenslet's phase is undersampled at its rim: ``r_max > lambda f / (2 dx)``.
    """
    require_positive("wavelength", wavelength, "m", "pass the vacuum wavelength in metres, e.g. 525 * nm.")
    require_positive("refractive_index", refractive_index, "", "use 1.0 for air, 1.33 for water.")
    if device is None and focal_lengths is not None:
        device = focal_lengths.device
    device = torch.device("cpu") if device is None else torch.device(device)
    f = _focal_lengths(mla, focal_lengths, device)
    medium_wavelength = wavelength / refractive_index
    k = 2.0 * math.pi / medium_wavelength
    f_values = f.detach().cpu().tolist()
    # Nyquist is per axis: the largest |x - cx| inside an aperture is its half-width (circle or square).
    worst = max(range(len(mla)), key=lambda i: mla[i].half_width / f_values[i])
    check_quadratic_phase_sampling(grid, medium_wavelength, f_values[worst], mla[worst].half_width)

    dy, dx = grid.spacing
    groups: dict[tuple[str, int, int], list[int]] = defaultdict(list)
    for i, lens in enumerate(mla):
        groups[
            (lens.shape, _patch_half_size(lens.half_width, dy), _patch_half_size(lens.half_width, dx))
        ].append(i)

    indices, values = [], []
    for (shape, hy, hx), members in groups.items():
        index, value = _place_group(mla, members, f, shape, (hy, hx), grid, k, antialias, dtype, device)
        indices.append(index)
        values.append(value)
    flat = torch.zeros(grid.ny * grid.nx, dtype=dtype, device=device)
    flat = flat.index_put((torch.cat(indices),), torch.cat(values), accumulate=True)
    return flat.view(grid.shape)


def _place_group(
    mla: MicrolensArray,
    members: list[int],
    f: torch.Tensor,
    shape: str,
    half: tuple[int, int],
    grid: Grid,
    k: float,
    antialias: bool,
    dtype: torch.dtype,
    device: torch.device,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Flat grid indices and complex values of all in-grid aperture pixels of one group."""
    hy, hx = half
    dy, dx = grid.spacing
    f64 = dict(dtype=torch.float64, device=device)
    centers = torch.tensor([mla[i].center for i in members], **f64)  # (G, 2) as (x, y)
    half_widths = torch.tensor([mla[i].half_width for i in members], **f64)
    ix0 = torch.round(centers[:, 0] / dx).long()  # nearest pixel, relative to the axis
    iy0 = torch.round(centers[:, 1] / dy).long()
    sub_x = centers[:, 0] - ix0.to(torch.float64) * dx  # long * float would round to float32
    sub_y = centers[:, 1] - iy0.to(torch.float64) * dy
    fg = f[torch.tensor(members, device=device)]

    # One patch per distinct (f, aperture, sub-pixel offset) unless gradients need one per lenslet.
    if fg.requires_grad:
        rep, inverse = torch.arange(len(members), device=device), None
    else:
        keys = torch.stack(
            [
                fg,
                half_widths,
                torch.round(sub_x / dx / _OFFSET_RESOLUTION),
                torch.round(sub_y / dy / _OFFSET_RESOLUTION),
            ],
            dim=1,
        )
        _, inverse = torch.unique(keys, dim=0, return_inverse=True)
        rep = torch.zeros(int(inverse.max()) + 1, dtype=torch.long, device=device)
        rep = rep.scatter(0, inverse, torch.arange(len(members), device=device))

    # Patch coordinates relative to the true centres: (U, 1, Px) and (U, Py, 1).
    px = torch.arange(-hx, hx + 1, **f64) * dx
    py = torch.arange(-hy, hy + 1, **f64) * dy
    xr = px[None, None, :] - sub_x[rep][:, None, None]
    yr = py[None, :, None] - sub_y[rep][:, None, None]
    half_width = half_widths[rep][:, None, None]
    if shape == "circle":
        coverage = disk_coverage(xr, yr, half_width, grid.spacing, antialias=antialias)
    else:
        coverage = square_coverage(xr, yr, 2.0 * half_width, grid.spacing, antialias=antialias)
    phase = (-0.5 * k) * (xr * xr + yr * yr) / fg[rep][:, None, None]
    patch = (coverage * torch.complex(torch.cos(phase), torch.sin(phase))).to(dtype)  # (U, Py, Px)
    if inverse is not None:
        patch, coverage = patch[inverse], coverage[inverse]

    rows = (iy0 + grid.ny // 2)[:, None, None] + torch.arange(-hy, hy + 1, device=device)[None, :, None]
    cols = (ix0 + grid.nx // 2)[:, None, None] + torch.arange(-hx, hx + 1, device=device)[None, None, :]
    rows, cols = torch.broadcast_tensors(rows, cols)
    keep = (coverage > 0) & (rows >= 0) & (rows < grid.ny) & (cols >= 0) & (cols < grid.nx)
    return (rows * grid.nx + cols)[keep], patch[keep]


def apply_mla(
    field: Field, mla: MicrolensArray, *, focal_lengths: torch.Tensor | None = None, antialias: bool = False
) -> Field:
    """Pass ``field`` (data ``(..., ny, nx)``) through ``mla`` placed on the field's grid.

    ``k`` is taken in the field's medium; see :func:`mla_transmission` for the
    parameters and what is differentiable.
    """
    transmission = mla_transmission(
        mla,
        field.grid,
        field.wavelength,
        refractive_index=field.refractive_index,
        focal_lengths=focal_lengths,
        antialias=antialias,
        dtype=field.dtype,
        device=field.device,
    )
    return field.with_data(field.data * transmission)
