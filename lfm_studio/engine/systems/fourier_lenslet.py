"""One lenslet of a Fourier LFM on its own small grid (single-FFT Fresnel transform).

For lenslet ``i`` the relayed pupil field ``U(r) = A(r / m_r) / m_r`` (``A`` from
:func:`pupil_field`, on-axis source, so the 4f inversion does not matter) is cut by
the lenslet aperture, multiplied by the lens phase and propagated ``d`` to the
sensor with the Fresnel impulse response in single-FFT form (thesis eq. 3.12):

    U_d(u) = 1/(j lambda d) e^{j k u^2/(2d)} FT{ U(x) e^{-j k x^2/(2f)} e^{j k x^2/(2d)} }(u / (lambda d))

(local coordinates about the lens centre). The lens and Fresnel chirps combine into
``k x^2 (1/d - 1/f) / 2`` (zero for a camera at the focal plane), the output phase
is dropped (only intensity is recorded), and a linear input phase moves the output
samples onto sensor sub-pixel centres (exact Fourier shift). The result is power
per sensor pixel of a unit-power emitter, ``(Z, N/s, N/s)``.
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine import fft
from lfm_studio.engine.dtypes import real_dtype
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.mla_layout import Lenslet
from lfm_studio.engine.optics.objective import _value
from lfm_studio.engine.optics.pixel_integration import integrate_pixels
from lfm_studio.engine.optics.pupil_field import pupil_terms
from lfm_studio.engine.optics.pupils import disk_coverage, square_coverage
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.fourier_windows import LensletWindow


def lenslet_psf(
    system: FourierLFMSystem,
    lens: Lenslet,
    window: LensletWindow,
    depths: torch.Tensor,
    *,
    oversampling: int,
    model: str = "debye",
    antialias: bool = True,
    dtype: torch.dtype = torch.float32,
    source_position: tuple[float, float] = (0.0, 0.0),
    depth_chunk: int = 8,
    pixel_integration: str = "midpoint",
) -> torch.Tensor:
    """Power per sensor pixel behind one lenslet for each depth.

    Parameters
    ----------
    system : the Fourier LFM.
    lens : the lenslet (centre in MLA-plane metres).
    window : its planned grid (:func:`plan_window`).
    depths : float64 tensor ``(Z,)`` of source depths in metres (sample side).
    oversampling : sub-samples per sensor pixel per axis (the ``s`` of the window).
    model : objective model, ``"debye"`` (exact defocus) or ``"paraxial"``.
    antialias : area-weighted aperture edge.
    dtype : real dtype of the result (the field is computed in the matching complex dtype).
    source_position : lateral (x0, y0) of the emitter in the sample, metres. The 4f relay
        inverts the pupil, so the relayed field at ``r`` is the pupil field at ``-r / m_r``;
        the defocus part is radially symmetric, which leaves the tilt: evaluated at
        ``+r / m_r`` with the source at ``(-x0, -y0)``.
    depth_chunk : depths per FFT batch (bounds memory; small chunks are cache-friendly on CPU).
    pixel_integration : ``"midpoint"`` or ``"fourier"`` (:func:`integrate_pixels`).

    Returns
    -------
    Tensor ``(Z, N/s, N/s)`` on ``depths.device``: power per pixel (W per W emitted).
    """
    n, dx = window.samples, window.input_spacing
    m_r = system.relay_magnification
    device = depths.device
    cx, cy = lens.center
    amplitude, defocus, tilt = pupil_terms(
        system.objective, Grid(n, dx / m_r), system.wavelength,
        position=(-source_position[0], -source_position[1]), center=(cx / m_r, cy / m_r), model=model, device=device,
    )  # fmt: skip
    aperture, static_phase = _lenslet_transmission(system, lens, window, antialias=antialias, device=device)
    step = system.pixel_pitch / oversampling
    scale = (dx * dx / (system.wavelength * system.mla_to_camera)) ** 2 * step * step / (m_r * m_r)
    amplitude = (amplitude * aperture * math.sqrt(scale)).to(real_dtype(dtype))
    static_phase = static_phase + tilt
    parts = []
    for start in range(0, depths.numel(), depth_chunk):
        phase = depths[start : start + depth_chunk, None, None] * defocus + static_phase  # float64
        if dtype == torch.float32:  # wrap in float64, then the float32 phasor is accurate to ~1e-7 rad
            phase = torch.remainder(phase, 2.0 * math.pi).to(torch.float32)
        parts.append(
            integrate_pixels(
                fft.centered_power(torch.polar(amplitude.expand_as(phase), phase)),
                oversampling,
                pixel_integration,
            )
        )
    return torch.cat(parts, dim=0)


def _lenslet_transmission(
    system: FourierLFMSystem, lens: Lenslet, window: LensletWindow, *, antialias: bool, device
) -> tuple[torch.Tensor, torch.Tensor]:
    """Aperture coverage and phase (lens + Fresnel chirp + output-shift ramp) on the lenslet patch, float64."""
    n, dx = window.samples, window.input_spacing
    y, x = Grid(n, dx).axes(device=device)
    xx, yy = x[None, :], y[:, None]
    if lens.shape == "circle":
        aperture = disk_coverage(xx, yy, lens.aperture_diameter / 2.0, (dx, dx), antialias=antialias)
    else:
        aperture = square_coverage(xx, yy, lens.aperture_diameter, (dx, dx), antialias=antialias)
    k = 2.0 * math.pi / system.wavelength
    d, f = system.mla_to_camera, float(_value(lens.focal_length))
    sy, sx = window.shift
    phase = 0.5 * k * (1.0 / d - 1.0 / f) * (xx**2 + yy**2) - k / d * (xx * sx + yy * sy)
    return aperture.to(torch.float64), phase
