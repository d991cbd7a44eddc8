"""Angular-spectrum transfer functions: exact and band-limited (Matsushima & Shimobaba 2009).

``H(fx, fy; z) = exp(j 2 pi z sqrt(1/l^2 - fx^2 - fy^2))`` with ``l = lambda / n`` the
wavelength in the medium, evanescent components (``f^2 >= 1/l^2``) dropped. The phase
is formed in float64 in the stable form

    2 pi z (sqrt(1/l^2 - f^2) - 1/l) = -2 pi z f^2 / (1/l + sqrt(1/l^2 - f^2)),

which keeps full relative precision at small ``f``; the constant ``exp(j k z)`` is
added to it (``include_constant_phase=True``, float64, error below 1e-10 rad at 26 mm)
or left out. Only the complex exponential is cast to the requested dtype.

For ``z < 0`` the kernel is the complex conjugate of the ``|z|`` kernel (the formula
is odd in ``z`` and the amplitude is 0 or 1): back-propagation never amplifies.

The band-limited kernel also zeroes ``|fx| > fx_limit`` and ``|fy| > fy_limit`` with
``f_limit = 1 / (l sqrt((2 df |z|)^2 + 1))`` and ``df = 1 / (padded extent)``
(:func:`~lfm_studio.engine.optics.sampling.bandlimit_frequency`), the frequencies whose
kernel would alias on the padded window.

Kernels are returned in FFT order (frequency index 0 first, numpy's ``fftfreq``), for
multiplying the output of :func:`lfm_studio.engine.fft.fft2` directly. ``H`` depends on
``|fx|`` and ``|fy|`` only, so it is built on one quadrant and mirrored (4x fewer
square roots and complex exponentials).
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.sampling import bandlimit_frequency

Scalar = float | torch.Tensor
Device = torch.device | str | None


def _half_frequencies(n: int, d: float, device: Device) -> torch.Tensor:
    """``|f|`` values ``j / (n d)`` for ``j = 0 .. n // 2`` (float64)."""
    return torch.arange(n // 2 + 1, device=device, dtype=torch.float64) / (n * d)


def _mirror_index(n: int, device: Device) -> torch.Tensor:
    """FFT-order index ``k -> min(k, n - k)`` into the half-frequency axis."""
    k = torch.arange(n, device=device)
    return torch.minimum(k, n - k)


def _value(distance: Scalar) -> float:
    return float(distance.detach()) if isinstance(distance, torch.Tensor) else float(distance)


def _as_float64(distance: Scalar, device: Device) -> Scalar:
    if isinstance(distance, torch.Tensor):
        return distance.to(device=device, dtype=torch.float64)
    return float(distance)


def asm_transfer_function(
    grid: Grid,
    wavelength: float,
    distance: Scalar,
    *,
    bandlimit: bool = False,
    include_constant_phase: bool = True,
    scale: float = 1.0,
    dtype: torch.dtype = torch.complex128,
    device: Device = None,
) -> torch.Tensor:
    """Angular-spectrum transfer function on ``grid`` (the padded grid), FFT order.

    Parameters
    ----------
    grid : Grid
        Grid of the (padded) field the kernel multiplies the DFT of.
    wavelength : float
        Wavelength in the medium ``lambda / n``, metres.
    distance : float or 0-d tensor
        Propagation distance ``z`` in metres (negative: back-propagation). A tensor
        keeps the graph (the band-limit mask is piecewise constant, so it uses the value).
    bandlimit : bool
        Apply the Matsushima-Shimobaba band limit of ``grid``.
    include_constant_phase : bool
        Multiply by ``exp(j k z)``; ``False`` gives ``H exp(-j k z)``.
    scale : float
        Multiplies the kernel (the propagator folds the inverse DFT's ``1 / (My Mx)`` in).
    dtype, device
        Complex dtype and device of the result (built in float64 and cast).

    Returns
    -------
    complex tensor ``(My, Mx)`` in FFT order.
    """
    inv_l = 1.0 / wavelength
    fy = _half_frequencies(grid.ny, grid.dy, device)
    fx = _half_frequencies(grid.nx, grid.dx, device)
    f2 = fy[:, None] ** 2 + fx[None, :] ** 2
    amplitude = (f2 < inv_l * inv_l).to(torch.float64)  # evanescent components dropped
    if bandlimit:
        limit_y, limit_x = bandlimit_frequency(grid, wavelength, _value(distance))
        amplitude.mul_((fy[:, None] <= limit_y) & (fx[None, :] <= limit_x))
    if scale != 1.0:
        amplitude.mul_(scale)
    # phase per metre, in place: -2 pi f^2 / (1/l + sqrt(1/l^2 - f^2)) [+ 2 pi / l]
    root = torch.clamp(inv_l * inv_l - f2, min=0.0).sqrt_().add_(inv_l)
    phase = f2.mul_(-2.0 * math.pi).div_(root)
    if include_constant_phase:
        phase.add_(2.0 * math.pi * inv_l)
    z = _as_float64(distance, device)
    phase = phase * z if isinstance(z, torch.Tensor) else phase.mul_(z)
    quadrant = torch.polar(amplitude, phase).to(dtype)  # cast before mirroring: half the bytes for complex64
    return quadrant.index_select(0, _mirror_index(grid.ny, device)).index_select(
        1, _mirror_index(grid.nx, device)
    )
