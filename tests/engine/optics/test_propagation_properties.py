"""Properties of free-space propagation: energy, reversibility, paraxial limit, precision,
gradients, batching, CPU = CUDA. Tolerances state their error budget."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine import fft
from lfm_studio.engine.optics.asm import asm_transfer_function
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.propagation import METHODS, propagate
from lfm_studio.engine.optics.sampling import bandlimit_frequency, fft_frequencies
from lfm_studio.engine.optics.sources import gaussian_beam
from lfm_studio.engine.units import mm, nm, um

C128, C64 = torch.complex128, torch.complex64
PROPAGATORS = [m for m in METHODS if m != "auto"]
PERIODIC = {"padding": 1.0, "check_sampling": False}  # circular convolution is exact for these


def _rel_l2(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm())


def _random_field(grid: Grid, wavelength: float, max_frequency: float, seed: int, dtype=C128) -> Field:
    """Random field whose spectrum fills ``|f| < max_frequency`` (cycles/m), zero beyond."""
    gen = torch.Generator().manual_seed(seed)
    fy, fx = (fft_frequencies(n, d) for n, d in zip(grid.shape, grid.spacing, strict=True))
    inside = (fy[:, None] ** 2 + fx[None, :] ** 2) < max_frequency**2
    spectrum = torch.randn(grid.shape, dtype=C128, generator=gen) * inside
    return Field(fft.ifft2(spectrum).to(dtype), grid, wavelength)


# -- energy, reversibility, evanescent waves ------------------------------------------------
def test_asm_conserves_energy_without_evanescent_content():
    wavelength = 500 * nm
    grid = Grid(64, 0.4 * wavelength)  # Nyquist 1.25 / lambda: the grid holds evanescent frequencies
    field = _random_field(grid, wavelength, 0.9 / wavelength, seed=1)
    out = propagate(field, 7.3 * wavelength, method="asm", **PERIODIC)
    # |H| = 1 on every propagating frequency and Parseval holds for the DFT: float64 round-off
    # of two FFTs of 4096 samples (~1e-15); 1e-12 leaves margin. A kernel with a wrong modulus
    # (e.g. exp(j kz) with kz evaluated in float32 and cast back) fails at 1e-8.
    assert float(out.power() / field.power()) == pytest.approx(1.0, abs=1e-12)


def test_evanescent_components_are_dropped_and_back_propagation_never_amplifies():
    wavelength = 500 * nm
    grid = Grid(64, 0.25 * wavelength)  # Nyquist 2 / lambda
    field = _random_field(grid, wavelength, 2.0 / wavelength, seed=2)  # a quarter of it evanescent
    spectrum = fft.fft2(field.data)
    fy, fx = (fft_frequencies(n, d) for n, d in zip(grid.shape, grid.spacing, strict=True))
    propagating = ((fy[:, None] ** 2 + fx[None, :] ** 2) < 1.0 / wavelength**2).to(torch.float64)
    expected_power = float((spectrum.abs() ** 2 * propagating).sum()) / grid.ny / grid.nx * grid.pixel_area
    assert expected_power < 0.9 * float(field.power())  # the test field really has evanescent power
    for z in (3 * wavelength, -3 * wavelength):  # forward, and backward: conjugate kernel
        out = propagate(field, z, method="asm", **PERIODIC)
        assert float(out.power()) == pytest.approx(expected_power, rel=1e-12)  # round-off, as above


@pytest.mark.parametrize("method", ["asm", "bandlimited_asm", "fresnel_tf"])
def test_forward_then_backward_is_the_identity_within_the_band(method):
    wavelength = 500 * nm
    grid = Grid(64, 0.6 * wavelength)
    field = _random_field(grid, wavelength, 0.8 / wavelength, seed=3)
    z = 5 * wavelength  # below the window's critical distance (23 lambda): no band limit acts
    there = propagate(field, z, method=method, **PERIODIC)
    back = propagate(there, -z, method=method, **PERIODIC)
    assert _rel_l2(there.data, field.data) > 0.1  # it did move
    assert _rel_l2(back.data, field.data) < 1e-12  # H(-z) H(z) = 1 in the band; round-off only


def test_forward_then_backward_impulse_response_returns_to_the_input_grid():
    wavelength = 500 * nm
    grid = Grid(48, 2 * um)
    field = _random_field(grid, wavelength, 0.2 / (2 * um), seed=4)
    z = 1 * mm
    there = propagate(field, z, method="fresnel_ir", **PERIODIC)
    back = propagate(there, -z, method="fresnel_ir", **PERIODIC)
    assert there.grid.dx == pytest.approx(wavelength * z / (48 * 2 * um))
    assert back.grid.same_as(grid)
    # Chirps cancel exactly and the DFT pair is unitary up to its 1/N: round-off only.
    assert _rel_l2(back.data, field.data) < 1e-12


def test_localised_field_round_trip_with_padding_and_band_limit():
    wavelength = 500 * nm
    grid = Grid(256, 1 * um)
    field = gaussian_beam(grid, wavelength, 8 * um, dtype=C128)
    z = 1.2 * mm  # beyond the padded critical distance 512 * 1 um^2 / 0.5 um = 1.02 mm
    there = propagate(field, z, method="bandlimited_asm")
    back = propagate(there, -z, method="bandlimited_asm")
    # w(z) = 25 um in a +-128 um window: the cropped power is erfc(sqrt(2) 128 / 25) ~ 1e-23,
    # an L2 error of its square root, 3e-12; the beam's spectrum at the band limit (4.2e5 / m)
    # is exp(-110). Only that and round-off remain.
    assert _rel_l2(back.data, field.data) < 1e-10


def test_band_limited_kernel_is_unit_modulus_inside_the_limit_zero_outside_and_conjugate_for_minus_z():
    wavelength = 500 * nm
    grid = Grid((96, 128), (0.4 * wavelength, 0.3 * wavelength))
    z = 40 * wavelength
    kernel = asm_transfer_function(grid, wavelength, z, bandlimit=True)
    limit_y, limit_x = bandlimit_frequency(grid, wavelength, z)
    fy, fx = (fft_frequencies(n, d) for n, d in zip(grid.shape, grid.spacing, strict=True))
    inside = (fy.abs() <= limit_y)[:, None] & (fx.abs() <= limit_x)[None, :]
    inside &= (fy[:, None] ** 2 + fx[None, :] ** 2) < 1 / wavelength**2
    assert limit_x < 0.5 / grid.dx  # the limit really cuts inside the grid's band
    assert torch.allclose(kernel.abs(), inside.to(torch.float64), rtol=0, atol=1e-15)
    back = asm_transfer_function(grid, wavelength, -z, bandlimit=True)
    # exp(-i phi) and conj(exp(i phi)) are two evaluations: equal to rounding (|H| <= 1).
    assert torch.allclose(back, kernel.conj(), rtol=0, atol=1e-14)


def test_band_limit_suppresses_the_aliasing_of_the_unlimited_kernel():
    wavelength = 500 * nm
    grid = Grid(64, 1 * um)
    y, x = grid.axes()
    aperture = Field(
        ((x.abs() < 2.5 * um)[None, :] & (y.abs() < 2.5 * um)[:, None]).to(C128), grid, wavelength
    )
    z = 500 * um  # twice the padded critical distance (256 um)
    reference = propagate(aperture, z, method="asm", padding=16.0, check_sampling=False).data  # z_c = 2 mm
    unlimited = propagate(aperture, z, method="asm", check_sampling=False).data
    limited = propagate(aperture, z, method="bandlimited_asm", check_sampling=False).data
    # The unlimited kernel wraps the high angles back into the window (measured 22% L2); the
    # band limit removes them, leaving the ringing of its sharp cut-off (measured 3.8%).
    assert _rel_l2(unlimited, reference) > 0.15
    assert _rel_l2(limited, reference) < 0.06


# -- paraxial limit -------------------------------------------------------------------------
def test_asm_equals_fresnel_in_the_paraxial_limit_with_the_predicted_difference():
    wavelength = 500 * nm
    grid = Grid(64, 2 * um)
    f_max = 0.02 / wavelength  # NA 0.02
    fy, fx = (fft_frequencies(n, d) for n, d in zip(grid.shape, grid.spacing, strict=True))
    f2 = fy[:, None] ** 2 + fx[None, :] ** 2
    inside = f2 < f_max**2
    gen = torch.Generator().manual_seed(5)
    phases = 2 * math.pi * torch.rand(grid.shape, dtype=torch.float64, generator=gen)
    spectrum = torch.polar(inside.to(torch.float64), phases)  # unit modulus on the disk
    field = Field(fft.ifft2(spectrum), grid, wavelength)
    z = 25 * mm
    asm = propagate(field, z, method="asm", **PERIODIC)
    fresnel = propagate(field, z, method="fresnel_tf", **PERIODIC)
    # Per frequency the kernels differ by the phase pi z l^3 f^4 / 4 (next term: 1 + l^2 f^2 / 2,
    # 2e-4 relative here); with a unit-modulus spectrum the relative L2 difference is the RMS
    # of |exp(j dphi) - 1| over the disk's samples, <= dphi(f_max) = 3.9e-4 rad.
    dphi = math.pi * z * wavelength**3 * f2[inside] ** 2 / 4.0
    predicted = float(torch.sqrt((2.0 - 2.0 * torch.cos(dphi)).mean()))
    difference = _rel_l2(asm.data, fresnel.data)
    assert difference < math.pi * z * wavelength**3 * f_max**4 / 4.0
    assert difference == pytest.approx(predicted, rel=1e-3)


# -- precision --------------------------------------------------------------------------------
@pytest.mark.parametrize("method", PROPAGATORS)
def test_float32_agrees_with_float64_over_26_mm_at_488_nm(method):
    wavelength, z = 488 * nm, 26 * mm
    grid = Grid(256, 4 * um)
    f64 = gaussian_beam(grid, wavelength, 100 * um, dtype=C128)
    out64 = propagate(f64, z, method=method)
    out32 = propagate(f64.to(dtype=C64), z, method=method)
    # Budget: complex64 rounding of the input and of the kernel (6e-8 RMS each) plus two
    # FFTs of 512^2 (pocketfft/MKL error grows like eps32 * sqrt(log2(512^2)) ~ 2.5e-7 RMS);
    # measured 1.0-1.6e-7, bound 1e-6. A kernel phase k z formed in float32 (3.3e5 rad, ulp
    # 0.03 rad) would exceed it 1000-fold (next test).
    error = _rel_l2(out32.data.to(C128), out64.data)
    assert error < 1e-6


def test_float32_phase_would_fail_the_precision_bound():
    # The reason kernels are built in float64: the same kernel phase formed in float32.
    wavelength, z = 488 * nm, 26 * mm
    k = 2 * math.pi / wavelength
    phase64 = torch.tensor(k * z, dtype=torch.float64) + torch.linspace(0, 1, 1000, dtype=torch.float64)
    exact = torch.polar(torch.ones_like(phase64), phase64)
    naive = torch.polar(torch.ones(1000), phase64.to(torch.float32)).to(C128)
    assert _rel_l2(naive, exact) > 1e-3  # 1000x the 1e-6 bound above


# -- gradients --------------------------------------------------------------------------------
GRAD_SETUP = {  # distance scale (m) per method on a 16 x 16 grid of 1 um pixels at 500 nm
    "asm": 20 * um,
    "bandlimited_asm": 150 * um,  # beyond the padded critical distance: the band limit acts
    "fresnel_tf": 20 * um,
    "fresnel_ir": 300 * um,
}


@pytest.mark.parametrize("method", PROPAGATORS)
def test_gradcheck_field_and_distance(method):
    wavelength = 500 * nm
    grid = Grid(16, 1 * um)
    gen = torch.Generator().manual_seed(7)
    data = torch.randn((16, 16), dtype=C128, generator=gen).requires_grad_(True)
    scale = torch.tensor(1.0, dtype=torch.float64, requires_grad=True)  # distance = scale * z0
    z0 = GRAD_SETUP[method]

    def run(data, scale):
        field = Field(data, grid, wavelength)
        return propagate(field, scale * z0, method=method, check_sampling=False).data

    assert torch.autograd.gradcheck(run, (data, scale), fast_mode=True)
    assert torch.autograd.gradcheck(lambda s: run(data.detach(), s), (scale,))


def test_gradient_flows_to_a_distance_tensor_and_matches_the_phase_derivative():
    # d/dz of a plane wave's on-axis phase through the ASM is k (constant phase included).
    wavelength = 500 * nm
    grid = Grid(16, 1 * um)
    field = Field(torch.ones((16, 16), dtype=C128), grid, wavelength)
    z = torch.tensor(10 * um, dtype=torch.float64, requires_grad=True)
    out = propagate(field, z, method="asm", **PERIODIC)
    torch.angle(out.data[8, 8]).backward()
    assert float(z.grad) == pytest.approx(2 * math.pi / wavelength, rel=1e-12)


# -- batching ---------------------------------------------------------------------------------
@pytest.mark.parametrize("method", PROPAGATORS)
def test_batch_dimensions_propagate_in_one_call_like_single_fields(method):
    wavelength = 500 * nm
    grid = Grid(48, 2 * um)
    fields = [gaussian_beam(grid, wavelength, w * um, dtype=C128) for w in (8, 9, 10, 11, 12, 13)]
    batch = Field(torch.stack([f.data for f in fields]).reshape(2, 3, 48, 48), grid, wavelength)
    z = 300 * um
    out = propagate(batch, z, method=method)
    for i, single in enumerate(fields):
        expected = propagate(single, z, method=method)
        assert torch.allclose(out.data.reshape(6, *out.data.shape[-2:])[i], expected.data, rtol=0, atol=1e-14)
    assert out.grid.same_as(expected.grid)


# -- devices ----------------------------------------------------------------------------------
# The devices are compared on a case that warns about its sampling (the warning is the same on both).
@pytest.mark.filterwarnings("ignore::lfm_studio.engine.errors.SamplingWarning")
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("method", PROPAGATORS)
@pytest.mark.parametrize("dtype", [C64, C128])
def test_cuda_matches_cpu(method, dtype):
    wavelength = 488 * nm
    grid = Grid(256, 2 * um)
    cpu = gaussian_beam(grid, wavelength, 30 * um, dtype=dtype)
    z = torch.tensor(5 * mm, dtype=torch.float64)
    out_cpu = propagate(cpu, z, method=method)
    out_gpu = propagate(cpu.to("cuda"), z.to("cuda"), method=method)
    assert out_gpu.device.type == "cuda"
    # Different FFT libraries: agreement to a few eps of the dtype times log2(N^2).
    tolerance = 1e-5 if dtype == C64 else 1e-12
    assert _rel_l2(out_gpu.data.cpu(), out_cpu.data) < tolerance
