"""Fourier lens (thesis eq. 3.17) against closed forms: Airy pattern, Gaussian beam, Parseval."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.special import j1

from lfm_studio.engine.errors import SamplingWarning
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.lenses import fourier_lens
from lfm_studio.engine.optics.pupils import apply_pupil, circular_pupil
from lfm_studio.engine.optics.sources import gaussian_beam, plane_wave
from lfm_studio.engine.units import mm, nm, um

WAVELENGTH = 500 * nm

# Airy set-up: pupil radius a = 16 pixels on a 512 grid, so the output spacing
# lambda f / (N dx) puts the first zero 0.6098 * N / 16 = 19.5 pixels from the axis.
# NA = a / f = 0.008: paraxial.
AIRY_N, AIRY_DX, AIRY_A, AIRY_F = 512, 10 * um, 160 * um, 20 * mm


def _airy_focus(dtype: torch.dtype, *, antialias: bool = True) -> Field:
    grid = Grid(AIRY_N, AIRY_DX)
    pupil = circular_pupil(grid, 2 * AIRY_A, antialias=antialias)
    field = apply_pupil(plane_wave(grid, WAVELENGTH, dtype=dtype), pupil)
    return fourier_lens(field, AIRY_F, distance=AIRY_F)


def _axis_profile(focus: Field) -> tuple[np.ndarray, np.ndarray]:
    """(u >= 0 in metres, j * U(u, 0) which is real for a centred even pupil)."""
    centre = AIRY_N // 2
    row = (1j * focus.data[centre, centre:]).to(torch.complex128).numpy()
    return np.arange(row.size) * focus.grid.dx, row


@pytest.fixture(scope="module")
def airy64() -> Field:
    return _airy_focus(torch.complex64)


def test_airy_output_grid_and_absolute_peak(airy64):
    # Output spacing is lambda f / (N dx) exactly (Grid.fourier_dual).
    assert airy64.grid.dx == pytest.approx(WAVELENGTH * AIRY_F / (AIRY_N * AIRY_DX), rel=1e-12)
    # |U(0)|^2 = (pi a^2 / (lambda f))^2 for a unit plane wave. Budget: the antialiased
    # pupil area is 2.6e-5 below pi a^2 at a = 16 px (centred on a pixel), doubled in the
    # intensity (measured -5.2e-5); float32 sum of ~800 values ~1e-6. Tolerance 1e-4.
    expected = (math.pi * AIRY_A**2 / (WAVELENGTH * AIRY_F)) ** 2
    peak = float(airy64.intensity()[AIRY_N // 2, AIRY_N // 2])
    assert peak == pytest.approx(expected, rel=1e-4)


def test_airy_peak_needs_the_antialiased_area():
    # The binary pupil's area is off by 0.9% at a = 16 px (peak -1.8%): the same check fails.
    focus = _airy_focus(torch.complex128, antialias=False)
    expected = (math.pi * AIRY_A**2 / (WAVELENGTH * AIRY_F)) ** 2
    peak = float(focus.intensity()[AIRY_N // 2, AIRY_N // 2])
    assert abs(peak / expected - 1) > 1e-3


def _crossing(u: np.ndarray, values: np.ndarray, level: float) -> float:
    """Where ``values`` first drops below ``level``: root of a cubic through 4 samples."""
    i = int(np.argmax(values < level))
    coeffs = np.polyfit(u[i - 2 : i + 2] / u[1], values[i - 2 : i + 2] - level, 3)
    roots = np.roots(coeffs)
    roots = roots[np.abs(roots.imag) < 1e-9].real * u[1]
    return float(roots[np.argmin(np.abs(roots - u[i]))])


def test_airy_first_zero_and_fwhm(airy64):
    # Exact: first zero of J1 / (2 pi) = 0.609835 and FWHM 0.514497 (in lambda / NA).
    na = AIRY_A / AIRY_F
    u, amp = _axis_profile(airy64)
    # First zero: sign change of the real amplitude, located by a cubic through 4 samples
    # (linear interpolation alone errs by 1e-3 here); the sinc factor does not move zeros.
    # Measured error 1e-4; the binary pupil gives 1.1e-3, so 5e-4 discriminates.
    zero = _crossing(u, amp.real, 0.0)
    assert zero == pytest.approx(0.609835 * WAVELENGTH / na, rel=5e-4)
    # FWHM from the half-maximum crossing of |U|^2 (same interpolation). The antialiased
    # pupil holds box-averaged samples, so the spectrum carries sinc^2(dx u / (lambda f)),
    # 1 - 8.5e-4 at the half maximum, which narrows the FWHM by 6e-4 (measured -6.1e-4).
    fwhm = 2 * _crossing(u, np.abs(amp) ** 2 / np.abs(amp[0]) ** 2, 0.5)
    assert fwhm == pytest.approx(0.514497 * WAVELENGTH / na, rel=1.5e-3)


def test_airy_radial_profile_in_2d(airy64):
    # Every pixel within the third dark ring (v < 10.17) against [2 J1(v) / v]^2 with
    # v = 2 pi a r / (lambda f), normalised to the peak. Budget: the pupil's pixel box
    # (sinc^2 deficit (pi dx fx)^2 / 3 < 3e-2 of the local value at v = 10, < 1e-3 in
    # the main lobe), edge-pixel error of the antialiased pupil and float32: 2e-3 of the peak.
    y, x = airy64.grid.axes()
    r = torch.sqrt(y[:, None] ** 2 + x[None, :] ** 2).numpy()
    v = 2 * math.pi * AIRY_A * r / (WAVELENGTH * AIRY_F)
    inside = v < 10.17
    vv = np.where(v == 0, 1.0, v)
    airy = np.where(v == 0, 1.0, (2 * j1(vv) / vv) ** 2)
    measured = airy64.intensity().double().numpy()
    measured = measured / measured[AIRY_N // 2, AIRY_N // 2]
    error = np.abs(measured - airy)[inside].max()
    assert error < 2e-3, error
    assert inside.sum() > 1000  # the check covers the pattern in 2D, not a few pixels


# Gaussian set-up: N dx^2 = 6.4e-9 m^2 >= lambda f = 5e-9 m^2, so the residual chirp
# is sampled at |1 - d/f| = 1 (d = 0 and 2 f). w0 = 20 px: truncation exp(-41),
# spectral aliasing exp(-987); the DFT equals the continuous FT to rounding.
GAUSS_N, GAUSS_DX, GAUSS_W0, GAUSS_F = 256, 5 * um, 100 * um, 10 * mm


@pytest.mark.parametrize("ratio", [0.0, 0.5, 1.0, 2.0], ids=["d=0", "d=f/2", "d=f", "d=2f"])
def test_gaussian_width_curvature_and_energy(ratio):
    grid = Grid(GAUSS_N, GAUSS_DX)
    beam = gaussian_beam(grid, WAVELENGTH, GAUSS_W0, dtype=torch.complex128)
    out = fourier_lens(beam, GAUSS_F, distance=ratio * GAUSS_F)
    # ABCD reference (d, lens f, f): 1/q_out = (1 - d/f)/f + j zR / f^2, i.e. width
    # w_f = lambda f / (pi w0) and phase curvature (1 - d/f) k / (2 f); the peak
    # amplitude pi w0^2 / (lambda f) follows from energy conservation.
    k = 2 * math.pi / WAVELENGTH
    w_f = WAVELENGTH * GAUSS_F / (math.pi * GAUSS_W0)
    curvature = (1 - ratio) * k / (2 * GAUSS_F)
    y, x = out.grid.axes()
    u2 = (y[:, None] ** 2 + x[None, :] ** 2).numpy()
    data = out.data.numpy()
    amplitude = np.pi * GAUSS_W0**2 / (WAVELENGTH * GAUSS_F) * np.exp(-u2 / w_f**2)
    # complex128 DFT of a Gaussian: relative error ~1e-13; tolerance 1e-10 of the peak.
    assert np.abs(np.abs(data) - amplitude).max() < 1e-10 * amplitude.max()
    significant = amplitude > 1e-3 * amplitude.max()
    phase = np.angle(data * np.conj(data[GAUSS_N // 2, GAUSS_N // 2]))
    # Within 2.6 w_f the chirp phase stays below pi for these parameters, so no unwrap.
    assert np.abs(phase - curvature * u2)[significant].max() < 1e-8
    fitted = np.polyfit(u2[significant], phase[significant], 1)[0]
    assert fitted == pytest.approx(curvature, abs=1e-6 * k / (2 * GAUSS_F))
    # Energy: exact by Parseval up to rounding.
    assert float(out.power()) == pytest.approx(float(beam.power()), rel=1e-12)


@pytest.mark.parametrize(("dtype", "tol"), [(torch.complex64, 1e-5), (torch.complex128, 1e-12)])
def test_energy_conserved_for_any_field(dtype, tol):
    # sum |U|^2 dA before = after, exactly by Parseval; tolerance = rounding of an FFT of
    # 64^2 values (eps * log2 N^2 with margin). Batch dims must pass through.
    gen = torch.Generator().manual_seed(3)
    grid = Grid((48, 64), (4 * um, 3 * um))
    data = torch.randn((2, 48, 64), dtype=dtype, generator=gen)
    field = Field(data, grid, WAVELENGTH, refractive_index=1.33)
    out = fourier_lens(field, 50 * mm, distance=50 * mm)
    assert out.data.shape == data.shape and out.dtype == dtype
    torch.testing.assert_close(out.power(), field.power(), rtol=tol, atol=0)
    # medium wavelength: spacing lambda f / (n N dx)
    assert out.grid.dx == pytest.approx(WAVELENGTH / 1.33 * 50 * mm / (64 * 3 * um), rel=1e-12)
    assert out.grid.dy == pytest.approx(WAVELENGTH / 1.33 * 50 * mm / (48 * 4 * um), rel=1e-12)


def test_undersampled_residual_chirp_warns():
    # N dx^2 = 6.4e-9 m^2 < |1 - d/f| lambda f = 1.5e-8 m^2 at d = -2 f.
    grid = Grid(GAUSS_N, GAUSS_DX)
    beam = gaussian_beam(grid, WAVELENGTH, GAUSS_W0, dtype=torch.complex64)
    with pytest.warns(SamplingWarning, match="undersampled"):
        fourier_lens(beam, GAUSS_F, distance=-2 * GAUSS_F)


def test_bad_parameters_are_named():
    field = plane_wave(Grid(16, 1 * um), WAVELENGTH)
    with pytest.raises(ValueError, match="focal_length must be a finite number > 0"):
        fourier_lens(field, 0.0, distance=1 * mm)
    with pytest.raises(ValueError, match="focal_length"):
        fourier_lens(field, float("nan"), distance=1 * mm)
    with pytest.raises(ValueError, match="distance must be finite"):
        fourier_lens(field, 1 * mm, distance=float("inf"))


def test_gradcheck_field_focal_length_and_distance():
    # Float64 finite differences on a 16^2 grid (lengths in mm keep the steps well scaled);
    # the output grid moves with f and the gradient is per output sample (docstring),
    # which is what gradcheck differentiates. fast_mode: random projections of the Jacobian.
    grid = Grid(16, 4 * um)  # N dx^2 = 2.6e-10 m^2 >= |1 - d/f| lambda f = 1.5e-10 m^2
    gen = torch.Generator().manual_seed(0)
    data = torch.randn((2, 16, 16), dtype=torch.complex128, generator=gen, requires_grad=True)
    f_mm = torch.tensor(1.0, dtype=torch.float64, requires_grad=True)
    d_mm = torch.tensor(0.7, dtype=torch.float64, requires_grad=True)

    def run(data, f_mm, d_mm):
        return fourier_lens(Field(data, grid, WAVELENGTH), f_mm * mm, distance=d_mm * mm).data

    assert torch.autograd.gradcheck(run, (data, f_mm, d_mm), fast_mode=True)
    assert torch.autograd.gradcheck(lambda f_mm: run(data.detach(), f_mm, d_mm.detach()), (f_mm,))


# The devices are compared on a case that warns about its sampling (the warning is the same on both).
@pytest.mark.filterwarnings("ignore::lfm_studio.engine.errors.SamplingWarning")
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    grid = Grid(64, 5 * um)
    beam = gaussian_beam(grid, WAVELENGTH, 40 * um, dtype=torch.complex64)
    cpu = fourier_lens(beam, 20 * mm, distance=15 * mm)
    gpu = fourier_lens(beam.to("cuda"), 20 * mm, distance=15 * mm)
    assert gpu.device.type == "cuda"
    torch.testing.assert_close(gpu.data.cpu(), cpu.data, rtol=1e-5, atol=1e-5 * float(cpu.data.abs().max()))
