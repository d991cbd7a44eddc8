"""Thin lens (thesis eq. 3.15): phase, pupil, focusing, sampling warning, errors, gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lfm_studio.engine.errors import SamplingWarning
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.lenses import fourier_lens, thin_lens
from lfm_studio.engine.optics.pupils import circular_pupil
from lfm_studio.engine.optics.sources import gaussian_beam, plane_wave
from lfm_studio.engine.units import mm, nm, um

WAVELENGTH = 500 * nm


def _numpy_asm(data: np.ndarray, dx: float, wavelength: float, z: float) -> np.ndarray:
    """Exact angular-spectrum propagation (test-local reference, evanescent waves dropped)."""
    ny, nx = data.shape
    fy, fx = np.fft.fftfreq(ny, dx)[:, None], np.fft.fftfreq(nx, dx)[None, :]
    arg = 1.0 / wavelength**2 - fx**2 - fy**2
    kernel = np.where(arg > 0, np.exp(2j * np.pi * z * np.sqrt(np.maximum(arg, 0.0))), 0.0)
    return np.fft.ifft2(np.fft.fft2(data) * kernel)


def test_phase_is_the_closed_form_in_the_medium_and_float64_accurate():
    # 256^2 grid at 1 um: the phase reaches ~350 rad at the corners. A float32 phase would
    # err by 1.5e-5 there; the float64 phase + complex64 cast errs by 4e-8 (measured).
    # Nyquist: half-extent 128 um <= lambda f / (2 n dx) = 150 um (n = 1) and 169 um (n = 1.33).
    grid = Grid(256, 1 * um)
    center = (3.3 * um, -2.7 * um)
    y, x = grid.axes()
    r2 = ((x[None, :] - center[0]) ** 2 + (y[:, None] - center[1]) ** 2).numpy()
    for n, f in ((1.0, 600 * um), (1.33, 900 * um)):
        k = 2 * math.pi * n / WAVELENGTH
        expected = np.exp(-1j * k * r2 / (2 * f))
        out128 = thin_lens(
            plane_wave(grid, WAVELENGTH, refractive_index=n, dtype=torch.complex128), f, center=center
        )
        assert np.abs(out128.data.numpy() - expected).max() < 1e-10  # float64 rounding of 350 rad: 6e-14
        out64 = thin_lens(
            plane_wave(grid, WAVELENGTH, refractive_index=n, dtype=torch.complex64), f, center=center
        )
        # complex64: only the cast of exp(j phase) rounds (~6e-8); a float32 phase would give ~2e-5.
        assert np.abs(out64.data.numpy() - expected).max() < 1e-6


def test_pupil_is_applied_around_the_lens_centre():
    grid = Grid(64, 1 * um)
    field = plane_wave(grid, WAVELENGTH, dtype=torch.complex128)
    center = (5.5 * um, -4.25 * um)
    out = thin_lens(field, 2 * mm, aperture_diameter=30 * um, center=center, antialias=True)
    pupil = circular_pupil(grid, 30 * um, center=center, antialias=True)
    torch.testing.assert_close(out.data.abs(), pupil, rtol=0, atol=1e-12)


def test_focuses_like_the_fourier_lens():
    # Thin lens on a Gaussian (d = 0), then an exact (test-local numpy) ASM over f,
    # against fourier_lens(d = 0). N dx^2 = lambda f makes both output grids equal.
    # Budget: the Fourier lens is paraxial; the Fresnel phase error at the beam's
    # angles (theta ~ w0 / f = 0.01) is k f theta^4 / 8 ~ 2e-4 rad (measured 3.2e-4 of the
    # peak); tolerance 1e-3 of the peak.
    n, f, w0 = 256, 10 * mm, 100 * um
    dx = math.sqrt(WAVELENGTH * f / n)
    grid = Grid(n, dx)
    beam = gaussian_beam(grid, WAVELENGTH, w0, dtype=torch.complex128)
    focus = fourier_lens(beam, f, distance=0.0)
    assert focus.grid.same_as(grid)
    lensed = thin_lens(beam, f)
    k = 2 * math.pi / WAVELENGTH
    propagated = _numpy_asm(lensed.data.numpy(), dx, WAVELENGTH, f) * np.exp(-1j * k * f)
    reference = focus.data.numpy()
    error = np.abs(propagated - reference).max() / np.abs(reference).max()
    assert error < 1e-3, error


def test_focuses_like_the_fourier_lens_with_the_engine_propagator():
    propagation = pytest.importorskip("lfm_studio.engine.optics.propagation")
    n, f, w0 = 256, 10 * mm, 100 * um
    grid = Grid(n, math.sqrt(WAVELENGTH * f / n))
    beam = gaussian_beam(grid, WAVELENGTH, w0, dtype=torch.complex128)
    focus = fourier_lens(beam, f, distance=0.0)
    propagated = propagation.propagate(thin_lens(beam, f), f, method="bandlimited_asm")
    k = 2 * math.pi / WAVELENGTH
    data = propagated.data * complex(math.cos(k * f), -math.sin(k * f))
    # same paraxial budget as the numpy reference above
    assert float((data - focus.data).abs().max() / focus.data.abs().max()) < 1e-3


def test_undersampled_lens_warns_and_the_limit_does_not():
    grid = Grid(64, 1 * um)
    field = plane_wave(grid, WAVELENGTH)
    # aperture radius 20 um vs lambda f / (2 dx) = 0.25 * f / um: limit at f = 80 um.
    with pytest.warns(SamplingWarning, match="undersampled"):
        thin_lens(field, 60 * um, aperture_diameter=40 * um)
    thin_lens(field, 80 * um, aperture_diameter=40 * um)  # exactly at Nyquist: no warning (error in pytest)
    # Without a pupil the binding radius is the grid's half-extent along an axis (32 um).
    with pytest.warns(SamplingWarning, match="undersampled"):
        thin_lens(field, 120 * um)
    thin_lens(field, 128 * um)


def test_named_errors():
    field = plane_wave(Grid(16, 1 * um), WAVELENGTH)
    with pytest.raises(ValueError, match=r"focal_length must be a finite number > 0 m; got -0\.001 m"):
        thin_lens(field, -1 * mm)
    with pytest.raises(ValueError, match="focal_length must be a finite number > 0 m; got nan"):
        thin_lens(field, float("nan"))
    with pytest.raises(ValueError, match="aperture_diameter must be a finite number > 0 m; got 0 m"):
        thin_lens(field, 1 * mm, aperture_diameter=0.0)
    with pytest.raises(ValueError, match="focal_length"):
        thin_lens(field, torch.tensor(0.0))


def test_gradcheck_field_and_focal_length():
    # f = 100 um on a 16^2 grid of 1 um: phase up to ~8 rad, sampled (limit 25 um > 8 um).
    grid = Grid(16, 1 * um)
    gen = torch.Generator().manual_seed(0)
    data = torch.randn((2, 16, 16), dtype=torch.complex128, generator=gen, requires_grad=True)
    f_um = torch.tensor(100.0, dtype=torch.float64, requires_grad=True)

    def run(data, f_um):
        return thin_lens(Field(data, grid, WAVELENGTH), f_um * um, aperture_diameter=12 * um).data

    assert torch.autograd.gradcheck(run, (data, f_um), fast_mode=True)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    grid = Grid(64, 1 * um)
    field = plane_wave(grid, WAVELENGTH)
    cpu = thin_lens(field, 500 * um, aperture_diameter=40 * um, center=(1.3 * um, 0.0), antialias=True)
    gpu = thin_lens(
        field.to("cuda"), 500 * um, aperture_diameter=40 * um, center=(1.3 * um, 0.0), antialias=True
    )
    assert gpu.device.type == "cuda"
    torch.testing.assert_close(gpu.data.cpu(), cpu.data, rtol=0, atol=1e-6)
