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
pixels) plus allocating the output, never O(lenslets x grid). A patch never
extends further than the grid: on a one-row grid it is one row, however large the
lenslet.

Shared edges: touching lenslets partition the plane, so a sample's total aperture
coverage is at most 1. A binary mask (``antialias=False``) counts a sample on a rim
as inside, so a sample on the edge two squares share (or the contact point of two
circles) is claimed by both, and a corner sample by four. Wherever the claimed
coverages sum above 1 each claim is scaled by ``1 / sum``: an edge sample then
transmits the mean of its lenslets' phases with weight 1/2 each (a corner 1/4),
which is what the antialiased path gives for a pixel centred on that edge (each
lenslet covers half of it). Hence ``|t| <= 1`` everywhere, for every layout, shape
and antialiasing, and a 3 x 3 array of touching squares covers exactly the samples
of one square of the array's total size. (A binary rim that no neighbour shares still
counts whole, as for a lone aperture: with rims on samples a lenslet of ``m`` samples
across then focuses ``((m + 1) / m)^4`` too bright, whether alone or in the array; the
antialiased path has no such bias.)

Window edges: a lenslet that crosses the edge of the grid is cropped
(``periodic=False``, for an isolated array with a margin around it). With
``periodic=True`` the grid is one period of an infinite array: the parts of a
lenslet outside the window wrap around to the opposite edge (indices modulo the
grid size), so a periodic array needs no extra wrap-around lenslet.

Differentiability: with respect to the field and to the focal lengths (tensor
``Lenslet.focal_length`` entries or the ``focal_lengths`` override, e.g. an
``nn.Parameter`` of shape ``(L,)``); then every lenslet gets its own patch.
Centres and diameters are geometry (floats); their placement is discrete.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from collections import defaultdict

import torch

from lfm_studio.engine.errors import require_finite_tensor, require_positive
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.mla_layout import MicrolensArray
from lfm_studio.engine.optics.phase_kernels import aperture_coverage, lens_phase, unit_phasor
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


def _reach(centres: torch.Tensor, size: int, half: int, periodic: bool) -> int:
    """Patch half-size (pixels) needed on an axis of ``size`` samples: never more than ``half``.

    ``centres`` are the members' centre indices on that axis (0 .. size - 1 inside the
    grid). Cropped: the farthest grid sample from any centre. Periodic: offsets modulo
    ``size`` repeat, so ``size // 2`` (every residue once) is enough.
    """
    if periodic:
        return min(half, size // 2)
    farthest = int(torch.maximum(centres.abs(), (size - 1 - centres).abs()).max())
    return max(0, min(half, farthest))


def mla_transmission(
    mla: MicrolensArray,
    grid: Grid,
    wavelength: float,
    *,
    refractive_index: float = 1.0,
    focal_lengths: torch.Tensor | None = None,
    antialias: bool = False,
    periodic: bool = False,
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
    periodic : bool
        ``True``: the grid is one period of an infinite array; lenslet parts beyond an
        edge wrap around to the opposite edge. ``False``: they are cropped.
    dtype, device : complex dtype and device of the result.

    Samples claimed by several touching lenslets are shared (coverage capped at 1; see
    the module docstring), so ``|t| <= 1``.

    Raises
    ------
    ValueError
        With ``periodic=True``, when a lenslet is wider than the grid (it would overlap
        its own periodic copy).

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
    if periodic:
        _check_fits_period(mla, grid)
    groups: dict[tuple[str, int, int], list[int]] = defaultdict(list)
    for i, lens in enumerate(mla):
        groups[
            (lens.shape, _patch_half_size(lens.half_width, dy), _patch_half_size(lens.half_width, dx))
        ].append(i)

    indices, values, coverages = [], [], []
    for (shape, hy, hx), members in groups.items():
        index, value, coverage = _place_group(
            mla, members, f, shape, (hy, hx), grid, k, antialias, periodic, dtype, device
        )
        indices.append(index)
        values.append(value)
        coverages.append(coverage)
    index, value, coverage = torch.cat(indices), torch.cat(values), torch.cat(coverages)
    # Touching lenslets partition the plane: cap each sample's total coverage at 1.
    total = torch.zeros(grid.ny * grid.nx, dtype=coverage.dtype, device=device)
    total = total.index_put((index,), coverage, accumulate=True)
    value = value * (1.0 / total[index].clamp_min(1.0)).to(value.real.dtype)
    flat = torch.zeros(grid.ny * grid.nx, dtype=dtype, device=device)
    flat = flat.index_put((index,), value, accumulate=True)
    return flat.view(grid.shape)


def _check_fits_period(mla: MicrolensArray, grid: Grid) -> None:
    """A periodic window must be at least as wide as every lenslet (else it overlaps its copy)."""
    height, width = grid.ny * grid.spacing[0], grid.nx * grid.spacing[1]
    for i, lens in enumerate(mla):
        if lens.aperture_diameter > min(width, height) * (1.0 + 1e-9):
            raise ValueError(
                f"periodic=True needs every lenslet to fit in the grid ({width / 1e-6:.6g} x "
                f"{height / 1e-6:.6g} um); {lens.describe(i)} is wider. Fix: enlarge the grid or use "
                "periodic=False."
            )


def _place_group(
    mla: MicrolensArray,
    members: list[int],
    f: torch.Tensor,
    shape: str,
    half: tuple[int, int],
    grid: Grid,
    k: float,
    antialias: bool,
    periodic: bool,
    dtype: torch.dtype,
    device: torch.device,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Flat grid indices, complex values and coverages of all in-grid aperture pixels of one group."""
    dy, dx = grid.spacing
    f64 = torch.float64
    centers = torch.tensor([mla[i].center for i in members], dtype=f64, device=device)  # (G, 2) as (x, y)
    half_widths = torch.tensor([mla[i].half_width for i in members], dtype=f64, device=device)
    ix0 = torch.round(centers[:, 0] / dx).long()  # nearest pixel, relative to the axis
    iy0 = torch.round(centers[:, 1] / dy).long()
    sub_x = centers[:, 0] - ix0.to(torch.float64) * dx  # long * float would round to float32
    sub_y = centers[:, 1] - iy0.to(torch.float64) * dy
    fg = f[torch.tensor(members, device=device)]
    hy = _reach(iy0 + grid.ny // 2, grid.ny, half[0], periodic)
    hx = _reach(ix0 + grid.nx // 2, grid.nx, half[1], periodic)

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
    px = torch.arange(-hx, hx + 1, dtype=f64, device=device) * dx
    py = torch.arange(-hy, hy + 1, dtype=f64, device=device) * dy
    xr = px[None, None, :] - sub_x[rep][:, None, None]
    yr = py[None, :, None] - sub_y[rep][:, None, None]
    diameter = 2.0 * half_widths[rep][:, None, None]
    coverage = aperture_coverage(shape, xr, yr, diameter, grid.spacing, antialias=antialias)
    phase = lens_phase(xr, yr, fg[rep][:, None, None], k)
    patch = (coverage * unit_phasor(phase, torch.complex128)).to(dtype)  # (U, Py, Px)
    if inverse is not None:
        patch, coverage = patch[inverse], coverage[inverse]

    rows = (iy0 + grid.ny // 2)[:, None, None] + torch.arange(-hy, hy + 1, device=device)[None, :, None]
    cols = (ix0 + grid.nx // 2)[:, None, None] + torch.arange(-hx, hx + 1, device=device)[None, None, :]
    rows, cols = torch.broadcast_tensors(rows, cols)
    keep = coverage > 0
    if periodic:
        rows, cols = rows % grid.ny, cols % grid.nx
    else:
        keep = keep & (rows >= 0) & (rows < grid.ny) & (cols >= 0) & (cols < grid.nx)
    return (rows * grid.nx + cols)[keep], patch[keep], coverage.detach()[keep]


def apply_mla(
    field: Field,
    mla: MicrolensArray,
    *,
    focal_lengths: torch.Tensor | None = None,
    antialias: bool = False,
    periodic: bool = False,
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
        periodic=periodic,
        dtype=field.dtype,
        device=field.device,
    )
    return field.with_data(field.data * transmission)
