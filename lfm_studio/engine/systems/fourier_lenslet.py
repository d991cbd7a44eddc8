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

Every phase and aperture comes from :mod:`~lfm_studio.engine.optics.phase_kernels` (the
same functions as the public elements). The window (``N``, placement) is planned from
floats; the physics is evaluated from :class:`LensletOptics`, whose values may be 0-d
tensors: the result is then differentiable in the lenslet's focal length, aperture and
centre, the wavelength, NA, the relay and camera distances, a pupil phase mask and the
Zernike pupil-phase coefficients (formed by :func:`pupil_terms_at`, as in the full-field path).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from functools import cached_property

import torch

from lfm_studio.engine import fft
from lfm_studio.engine.dtypes import real_dtype
from lfm_studio.engine.optics.mla_layout import Lenslet
from lfm_studio.engine.optics.phase_kernels import (
    aperture_coverage,
    fresnel_chirp,
    lens_phase,
    shift_ramp,
    wavenumber,
)
from lfm_studio.engine.optics.pixel_integration import integrate_pixels
from lfm_studio.engine.optics.pupil_field import pupil_terms_at
from lfm_studio.engine.systems.fourier_parameters import LensletOptics
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
    optics: LensletOptics | None = None,
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
    optics : the values the physics uses (:class:`LensletOptics`, possibly tensors carrying
        gradients); default the plain floats of ``system`` and ``lens``. The window stays the
        one planned from floats.

    Returns
    -------
    Tensor ``(Z, N/s, N/s)`` on ``depths.device``: power per pixel (W per W emitted).
    """
    prepared = _prepare(
        system, lens, window, depths, oversampling, model, antialias, dtype, source_position, optics
    )
    parts = []
    for start in range(0, depths.numel(), depth_chunk):
        parts.append(
            integrate_pixels(
                prepared.power(depths[start : start + depth_chunk]), oversampling, pixel_integration
            )
        )
    return torch.cat(parts, dim=0)


def lenslet_field(
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
    optics: LensletOptics | None = None,
) -> torch.Tensor:
    """Complex field behind one lenslet on its window's sensor sub-pixel grid, ``(Z, N, N)``.

    The same computation as :func:`lenslet_psf` (``|field|^2`` summed over ``s x s`` blocks
    is its midpoint-rule result), with the phase kept up to a factor that depends only on the
    output sample: the Fresnel output chirp about the lens centre ``c`` is
    ``k |u - c|^2 / (2 d) = k |u|^2 / (2 d) - k u.c / d + k |c|^2 / (2 d)`` (``u`` the sample's
    sensor position); the first term, the sign of the centred DFT, ``1 / (j lambda d)`` and
    ``e^{j k d}`` are the same for every lenslet computed on the same sample grid and are
    dropped; the rest is a separable phasor per lenslet. Fields of lenslets planned on one
    shared window (:func:`~lfm_studio.engine.systems.fourier_windows.shared_window`) therefore
    add coherently sample by sample ("per_lenslet_coherent" in :func:`fourier_psf_stack`).
    ``|field|^2`` is power per sub-sample (W per W emitted).
    """
    return prepare_lenslet(
        system, lens, window, depths, oversampling, model, antialias, dtype, source_position, optics
    ).field(depths)


class LensletInput:
    """The depth-independent parts of one lenslet's input field (see :func:`lenslet_psf`)."""

    def __init__(self, amplitude, static_phase, defocus, dtype, checker_phase, output_ramp) -> None:
        self.amplitude, self.static_phase, self.defocus = amplitude, static_phase, defocus
        self.dtype = dtype
        self._checker_phase = checker_phase
        self._output_ramp = output_ramp
        self._box: LensletInput | None = None

    def power(self, depths: torch.Tensor) -> torch.Tensor:
        """``|field|^2`` ``(Z, N, N)``: power per output sub-sample (W per W emitted), the
        centred DFT's modulus squared (:func:`lenslet_psf`; the phase is not needed here)."""
        spectrum = self._box_spectrum(depths)
        return spectrum.real**2 + spectrum.imag**2

    def field(self, depths: torch.Tensor) -> torch.Tensor:
        """The complex output field ``(Z, N, N)`` with its relative phase (:func:`lenslet_field`).

        The box's offset ``o`` (:meth:`_box_spectrum`) becomes the output phase ``-2 pi o m / N``
        (in the ramps).
        """
        (r0, _), (c0, _) = self._support
        n = self.static_phase.shape[-1]
        spectrum = self._box_spectrum(depths)
        m = torch.arange(n, dtype=torch.float64, device=spectrum.device)
        ramp_y = self._phasor(self._output_ramp[0] - (2.0 * math.pi / n) * r0 * m)
        ramp_x = self._phasor(self._output_ramp[1] - (2.0 * math.pi / n) * c0 * m)
        return spectrum * ramp_y[:, None] * ramp_x[None, :]

    def _box_spectrum(self, depths: torch.Tensor) -> torch.Tensor:
        """The centred DFT ``(Z, N, N)`` of the input field, up to the box offset's output phase.

        Only the box of input samples where the amplitude is non-zero (the aperture: about 6 %
        of the XLFM patches) is evaluated and transformed, each axis zero-padded to ``N``: rows
        first, then the columns on a transposed copy (a DFT along the strided axis is slower).
        Against the whole patch (phasor of every sample, ``fft2``) 3.4-4x less work here.
        """
        n = self.static_phase.shape[-1]
        box = self._boxed()
        phase = depths[:, None, None] * box.defocus + box.static_phase  # float64
        if self.dtype == torch.float32:  # wrap in float64, then the float32 phasor is accurate to ~1e-7 rad
            phase = torch.remainder(phase, 2.0 * math.pi).to(torch.float32)
        rows = fft.fft_along(torch.polar(box.amplitude.expand_as(phase), phase), n, dim=-1)
        return fft.fft_along(rows.mT.contiguous(), n, dim=-1).mT

    @cached_property
    def _support(self) -> tuple[tuple[int, int], tuple[int, int]]:
        """Row and column ranges of the non-zero amplitude, 2 samples wider (clipped)."""
        nonzero = self.amplitude.detach() != 0
        n_y, n_x = nonzero.shape[-2:]
        rows = torch.nonzero(nonzero.any(dim=-1)).flatten()
        cols = torch.nonzero(nonzero.any(dim=-2)).flatten()
        if rows.numel() == 0:
            return (0, 1), (0, 1)
        return (
            (max(int(rows[0]) - 2, 0), min(int(rows[-1]) + 3, n_y)),
            (max(int(cols[0]) - 2, 0), min(int(cols[-1]) + 3, n_x)),
        )

    def _boxed(self) -> LensletInput:
        if self._box is None:
            (r0, r1), (c0, c1) = self._support
            box = (..., slice(r0, r1), slice(c0, c1))
            static = self.static_phase[box] + self._checker_phase[box]  # centred DFT
            self._box = LensletInput(
                self.amplitude[box],
                static,
                self.defocus[box],
                self.dtype,
                self._checker_phase,
                self._output_ramp,
            )
        return self._box

    def _phasor(self, phase: torch.Tensor) -> torch.Tensor:
        phase = torch.remainder(phase, 2.0 * math.pi).to(real_dtype(self.dtype))
        return torch.polar(torch.ones_like(phase), phase)


def prepare_lenslet(
    system: FourierLFMSystem,
    lens: Lenslet,
    window: LensletWindow,
    depths: torch.Tensor,
    oversampling: int,
    model: str = "debye",
    antialias: bool = True,
    dtype: torch.dtype = torch.float32,
    source_position: tuple[float, float] = (0.0, 0.0),
    optics: LensletOptics | None = None,
) -> LensletInput:
    """The depth-independent input of one lenslet (arguments as :func:`lenslet_psf`; ``depths``
    only gives the device)."""
    return _prepare(
        system, lens, window, depths, oversampling, model, antialias, dtype, source_position, optics
    )


def _prepare(
    system, lens, window, depths, oversampling, model, antialias, dtype, source_position, optics
) -> LensletInput:
    v = optics if optics is not None else LensletOptics.of(system, lens)
    n, s, p = window.samples, oversampling, system.pixel_pitch
    lam, d, m_r = _f64(v.wavelength), _f64(v.mla_to_camera), _f64(v.relay_magnification)
    device = depths.device
    # Input spacing lambda d s / (N p) keeps the output on the sensor's sub-pixel grid.
    dx = lam * d * s / (n * p)
    index = torch.arange(n, dtype=torch.float64, device=device) - n // 2
    ix, iy = index[None, :], index[:, None]
    x, y = ix * dx, iy * dx  # about the lens centre
    cx, cy = (_f64(c) for c in v.center)
    amplitude, defocus, tilt = pupil_terms_at(
        v.objective, (x + cx) / m_r, (y + cy) / m_r, lam,
        position=(-source_position[0], -source_position[1]), model=model,
        soft_edge_spacing=dx / m_r if v.soft_pupil_edge else None, zernike_waves=dict(v.zernike_waves),
    )  # fmt: skip
    # Coverage in units of samples (scale-free): the aperture then follows dx's gradient too.
    aperture = aperture_coverage(
        lens.shape, ix, iy, _f64(v.aperture_diameter) / dx, (1.0, 1.0), antialias=antialias
    )
    k = wavenumber(lam)
    sy, sx = window.shift
    # The window was placed for the planned centre; a moved centre shifts the output back.
    shift = (sx + (lens.center[0] - cx), sy + (lens.center[1] - cy))
    static_phase = (
        lens_phase(x, y, _f64(v.focal_length), k)
        + fresnel_chirp(x, y, d, k)
        + shift_ramp(x, y, shift, k, d)
        + tilt
    )
    if v.pupil_phase is not None:
        static_phase = static_phase + v.pupil_phase.sample(x + cx, y + cy)
    step = p / s
    scale = (dx * dx / (lam * d)) ** 2 * step * step / (m_r * m_r)
    amplitude = (amplitude * aperture * scale**0.5).to(real_dtype(dtype))
    # Centred DFT of an even N (origin at index N // 2 in both domains), per axis:
    # (-1)^(N/2) (-1)^m fft((-1)^n g)[m] for array indices n, m; the (-1)^m and, the window
    # being square, the (-1)^(N/2) are common to every lenslet on the grid (lenslet_field).
    odd = torch.arange(n, device=device).remainder(2).to(torch.float64)
    checker_phase = math.pi * (odd[:, None] + odd[None, :])
    # Output sample m sits at u = c + (m - N//2) step + shift; keep k (|c|^2 / 2 - u.c) / d per axis.
    ux, uy = index * step + shift[0] + cx, index * step + shift[1] + cy
    ramp = ((0.5 * cy - uy) * cy * k / d, (0.5 * cx - ux) * cx * k / d)
    return LensletInput(amplitude, static_phase, defocus, dtype, checker_phase, ramp)


def _f64(value: float | torch.Tensor) -> float | torch.Tensor:
    """A float stays a float; a tensor becomes float64 (graph kept)."""
    return value.to(torch.float64) if isinstance(value, torch.Tensor) else float(value)
