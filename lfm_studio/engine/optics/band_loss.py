"""The band-limit check on a field's spectrum, run by :func:`propagate` between its FFTs.

Beyond about the critical distance the band limit of Matsushima & Shimobaba (2009) falls
below Nyquist: the band-limited ASM removes the frequencies beyond it (the angles that
would leave the padded window) and unlimited kernels (``"asm"``, ``"fresnel_tf"``) alias
them. Whether that matters depends on the power the field has there, which only its
spectrum tells; this module measures it and warns (:class:`SamplingWarning`) naming the
padded grid that would keep the field's bandwidth. Evanescent power does not count.
Lengths in metres, frequencies in cycles per metre, ``wavelength`` in the medium.
"""

from __future__ import annotations

import torch

from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.sampling import (
    MAX_GRID_SAMPLES,
    bandlimit_frequency,
    critical_distance,
    describe_grid,
    fft_frequencies,
    nyquist_frequency,
    padded_shape_for_bandwidth,
    slice_power,
    warn_sampling,
)

BAND_LOSS_TOLERANCE = 1e-3  # fraction of the power a band limit may remove (or a kernel may alias)


def _bandwidth(frequencies: torch.Tensor, profile: torch.Tensor, allowed: float) -> float:
    """Smallest ``f`` with at most ``allowed`` of ``profile``'s power at ``|frequency| > f``."""
    radius = frequencies.abs()
    order = radius.argsort(descending=True)
    tail = profile[order].cumsum(0)
    first = (tail > allowed).nonzero()
    return float(radius[order][first[0]]) if len(first) else 0.0


def _runs(mask: torch.Tensor) -> list[slice]:
    """Contiguous runs of True in a 1D mask, as slices (FFT order: at most two)."""
    index = mask.nonzero().flatten().tolist()
    runs, start = [], None
    for i, k in enumerate(index):
        if start is None:
            start = k
        if i + 1 == len(index) or index[i + 1] != k + 1:
            runs.append(slice(start, k + 1))
            start = None
    return runs


def _power_in_box(spectrum: torch.Tensor, keep_y: torch.Tensor, keep_x: torch.Tensor) -> torch.Tensor:
    """Power of ``spectrum (B, My, Mx)`` at ``keep_y x keep_x``: the (corner) blocks, copied and dotted."""
    total = torch.zeros(spectrum.shape[0], dtype=torch.float64, device=spectrum.device)
    for rows in _runs(keep_y):
        for cols in _runs(keep_x):
            total = total + slice_power(spectrum[:, rows, cols])
    return total


def check_band_loss(
    spectrum: torch.Tensor,
    grid: Grid,
    wavelength: float,
    distance: float,
    *,
    method: str,
    tolerance: float = BAND_LOSS_TOLERANCE,
) -> bool:
    """Warn when the band limit removes (or the kernel aliases) more than ``tolerance`` of the power.

    Runs only when the band limit of the padded ``grid`` is below Nyquist on an axis
    (``z`` beyond about the critical distance). Evanescent power does not count: dropping
    it is physics. Warning only on power actually present keeps band-limited fields
    (e.g. a smooth beam on a fine grid) free of spurious warnings.

    Parameters
    ----------
    spectrum : complex tensor ``(..., My, Mx)``, the DFT (FFT order) of the padded field.
    grid : the padded grid.
    wavelength : wavelength in the medium, metres.
    distance : metres.
    method : ``"bandlimited_asm"`` (the limit removes power) or ``"asm"``/``"fresnel_tf"``
        (the unlimited kernel aliases beyond it), for the message.
    """
    limits = bandlimit_frequency(grid, wavelength, distance)
    if all(fl >= fn for fl, fn in zip(limits, nyquist_frequency(grid), strict=True)):
        return True
    with torch.no_grad():
        spectrum = spectrum.reshape(-1, *grid.shape)
        fy, fx = (
            fft_frequencies(n, d, spectrum.device) for n, d in zip(grid.shape, grid.spacing, strict=True)
        )
        keep_y, keep_x = (f.abs() <= lim for f, lim in zip((fy, fx), limits, strict=True))
        cutoff2 = 1.0 / wavelength**2
        total = slice_power(spectrum)
        ratio = torch.where(total > 0, total, torch.ones_like(total))
        # Cheap upper bound first: all power outside the rectangle (evanescent included).
        lost_each = total - _power_in_box(spectrum, keep_y, keep_x)
        power = None
        evanescent = float(fy.abs().max()) ** 2 + float(fx.abs().max()) ** 2 >= cutoff2
        if float((lost_each / ratio).max()) > tolerance and evanescent:
            # Exact: dropping evanescent power is physics, not band-limit loss.
            power = spectrum.real**2 + spectrum.imag**2
            power.mul_((fy[:, None] ** 2 + fx[None, :] ** 2) < cutoff2)
            kept = keep_y.to(power.dtype) @ power @ keep_x.to(power.dtype)
            lost_each = power.sum(dim=(-2, -1)).double() - kept.double()
        lost = float((lost_each / ratio).max())
        if lost <= tolerance:
            return True
        if power is None:
            power = spectrum.real**2 + spectrum.imag**2
        allowed = 0.5 * tolerance * float(total.sum())
        bandwidth = (
            _bandwidth(fy, power.sum(dim=(0, 2)).double(), allowed),
            _bandwidth(fx, power.sum(dim=(0, 1)).double(), allowed),
        )
    need = padded_shape_for_bandwidth(grid, wavelength, distance, bandwidth)
    z = abs(float(distance))
    if method == "bandlimited_asm":
        what = (
            f"band limit (Matsushima-Shimobaba 2009) below Nyquist: it removes {lost:.3g} of the field's power "
            "(the angles that would leave the padded window)"
        )
    else:
        what = (
            f"{method} transfer function undersampled beyond the band limit (z > critical distance N dx^2 / lambda "
            f"= {critical_distance(grid, wavelength) / 1e-3:.4g} mm): {lost:.3g} of the field's power lies where the "
            "kernel aliases (wraps around the padded window)"
        )
    if need is None or need[0] * need[1] > MAX_GRID_SAMPLES:
        fix = "no padded grid within the size limit keeps the field's bandwidth; use method='fresnel_ir'"
    else:
        factor = max(m / n for m, n in zip(need, grid.shape, strict=True))
        fix = (
            f"a padded grid that satisfies it: {describe_grid(need, grid.spacing)} "
            f"(padding about {factor:.3g} x the current one)"
            + ("" if method == "bandlimited_asm" else ", or method='bandlimited_asm'")
        )
    warn_sampling(
        f"{what}; band limit (fy, fx) = ({limits[0] * 1e-6:.4g}, {limits[1] * 1e-6:.4g}) cycles/um vs Nyquist "
        f"({0.5e-6 / grid.dy:.4g}, {0.5e-6 / grid.dx:.4g}) cycles/um at z = {z / 1e-3:.4g} mm on padded "
        f"{describe_grid(grid.shape, grid.spacing)}. Fix: {fix}."
    )
    return False
