"""Fresnel propagation: transfer function (same grid) and impulse response (single FFT, new grid).

Transfer function (thesis, below eq. 3.12), ``l = lambda / n`` the wavelength in the medium::

    H(fx, fy) = exp(j k z) exp(-j pi l z (fx^2 + fy^2))

Impulse response / single-FFT form (thesis eqs. 3.11-3.12), output spacing
``l |z| / (M d)`` on an ``M``-sample (padded) input::

    U(x, y) = exp(j k z) / (j l z) exp(j k (x^2 + y^2) / (2 z))
              * sum U(xi, eta) exp(j k (xi^2 + eta^2) / (2 z)) exp(-j 2 pi (x xi + y eta) / (l z)) dxi deta

Both kernels are separable, so they are built and cached as two 1D factors (O(M)
work and memory, against O(M^2) for the ASM). Phases are formed in float64 and only
the complex exponentials are cast. With a 0-d tensor ``distance`` every factor stays
differentiable (the output sample positions of the impulse response move with ``z``,
and the output chirp is written as ``pi l z f^2`` so that gradients include it).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.phase_kernels import fresnel_chirp, wavenumber
from lfm_studio.engine.optics.sampling import fft_frequencies

Scalar = float | torch.Tensor
Device = torch.device | str | None


def _as_float64(distance: Scalar, device: Device) -> Scalar:
    if isinstance(distance, torch.Tensor):
        return distance.to(device=device, dtype=torch.float64)
    return float(distance)


def _unit(phase: torch.Tensor, amplitude: Scalar = 1.0) -> torch.Tensor:
    if isinstance(amplitude, torch.Tensor):
        return torch.polar(amplitude.expand_as(phase), phase)
    return torch.polar(torch.full_like(phase, float(amplitude)), phase)


def fresnel_transfer_factors(
    grid: Grid,
    wavelength: float,
    distance: Scalar,
    *,
    include_constant_phase: bool = True,
    scale: float = 1.0,
    dtype: torch.dtype = torch.complex128,
    device: Device = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Separable Fresnel transfer function ``H = hy[:, None] * hx[None, :]``, FFT order.

    Parameters
    ----------
    grid : the (padded) grid; wavelength : in the medium, metres; distance : metres,
    float or 0-d tensor; include_constant_phase : include ``exp(j k z)``; scale :
    multiplies ``H`` (the propagator folds the inverse DFT's ``1 / (My Mx)`` in).

    Returns
    -------
    ``(hy, hx)`` of shapes ``(My, 1)`` and ``(1, Mx)``.
    """
    z = _as_float64(distance, device)
    fy = fft_frequencies(grid.ny, grid.dy, device)
    fx = fft_frequencies(grid.nx, grid.dx, device)
    phase_y = (-math.pi * wavelength) * fy**2 * z
    if include_constant_phase:
        phase_y = phase_y + (2.0 * math.pi / wavelength) * z
    hy = _unit(phase_y, scale)
    hx = _unit((-math.pi * wavelength) * fx**2 * z)
    return hy.to(dtype)[:, None], hx.to(dtype)[None, :]


def fresnel_transfer_function(grid: Grid, wavelength: float, distance: Scalar, **kwargs) -> torch.Tensor:
    """The Fresnel transfer function as one ``(My, Mx)`` tensor in FFT order (see :func:`fresnel_transfer_factors`)."""
    hy, hx = fresnel_transfer_factors(grid, wavelength, distance, **kwargs)
    return hy * hx


def fresnel_ir_output_grid(grid: Grid, wavelength: float, distance: float) -> Grid:
    """Output grid of the impulse-response form: same shape, spacing ``l |z| / (M d)`` per axis."""
    z = abs(float(distance))
    return Grid(grid.shape, (wavelength * z / (grid.ny * grid.dy), wavelength * z / (grid.nx * grid.dx)))


def _ir_axis(n: int, d: float, wavelength: float, z: Scalar, sign: float, device: Device):
    """Input and output phases of one axis (float64), centred indices ``c = n // 2``.

    ``x_m xi_n / (l z) = sign (m - c)(n - c) / M`` splits into the DFT kernel
    ``exp(-j 2 pi sign m n / M)``, the ramps ``exp(j 2 pi sign c n / M)`` on input and
    output, and the constant ``exp(-j 2 pi sign c^2 / M)``.
    """
    c = n // 2
    k = torch.arange(n, device=device, dtype=torch.float64)
    ramp = (2.0 * math.pi * sign * c / n) * k
    xi = (k - c) * d
    f_out = (k - c) / (n * d)  # k x_m^2 / (2 z) = pi l z f_out^2
    phase_in = fresnel_chirp(xi, 0.0, z, wavenumber(wavelength)) + ramp
    phase_out = (math.pi * wavelength) * f_out**2 * z + ramp
    constant = -2.0 * math.pi * sign * c * c / n
    return phase_in, phase_out, constant


def fresnel_ir_factors(
    grid: Grid,
    wavelength: float,
    distance: Scalar,
    *,
    include_constant_phase: bool = True,
    dtype: torch.dtype = torch.complex128,
    device: Device = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Separable factors of the impulse-response form on the (padded) input ``grid``.

    ``U_out = out_y * out_x * DFT_sign(in_y * in_x * U_in)`` where ``DFT_sign`` is the
    unnormalised forward DFT for ``z > 0`` and the unnormalised inverse for ``z < 0``;
    ``out_y`` carries ``exp(j k z) / (j l z) * dy dx``.

    Returns
    -------
    ``(in_y, in_x, out_y, out_x)`` of shapes ``(My, 1), (1, Mx), (My, 1), (1, Mx)``.
    """
    z = _as_float64(distance, device)
    sign = 1.0 if float(distance.detach() if isinstance(distance, torch.Tensor) else distance) > 0 else -1.0
    in_y, out_y, const_y = _ir_axis(grid.ny, grid.dy, wavelength, z, sign, device)
    in_x, out_x, const_x = _ir_axis(grid.nx, grid.dx, wavelength, z, sign, device)
    # 1 / (j l z) = exp(-j sign pi / 2) / (l |z|)
    constant = const_y + const_x - sign * math.pi / 2.0
    out_y = out_y + constant
    if include_constant_phase:
        out_y = out_y + (2.0 * math.pi / wavelength) * z
    amplitude = grid.dy * grid.dx / (wavelength * (z.abs() if isinstance(z, torch.Tensor) else abs(z)))
    # y factors as columns, x factors as rows.
    return (
        _unit(in_y).to(dtype)[:, None],
        _unit(in_x).to(dtype)[None, :],
        _unit(out_y, amplitude).to(dtype)[:, None],
        _unit(out_x).to(dtype)[None, :],
    )
