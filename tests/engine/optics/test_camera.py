"""Camera: exact pixel integration and the staged sensor model (shot, read noise, ADC)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from lfm_studio.engine.optics.camera import (
    Camera,
    capture,
    digitize,
    expected_electrons,
    integrate_pixels,
    intensity,
    sample_electrons,
    simulate_sensor,
)
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.units import um

D = 1.0 * um  # sample spacing of the test grids


def box_integral_reference(image: np.ndarray, d: float, pitch: float, shape, offset) -> np.ndarray:
    """Independent reference: the exact integral of the piecewise-constant image over each
    pixel from the cumulative integral F(x) = integral_-inf^x (piecewise linear, so np.interp
    is exact), taken separably along y then x."""

    def along(axis_values: np.ndarray, n_out: int, off: float) -> np.ndarray:
        n = axis_values.shape[0]
        edges = (np.arange(n + 1) - n // 2 - 0.5) * d
        cumulative = np.concatenate(
            [np.zeros((1, *axis_values.shape[1:])), np.cumsum(axis_values * d, axis=0)]
        )
        pixel_edges = (np.arange(n_out + 1) - n_out // 2 - 0.5) * pitch + off
        flat = cumulative.reshape(n + 1, -1)
        values = np.stack([np.interp(pixel_edges, edges, flat[:, j]) for j in range(flat.shape[1])], axis=1)
        return np.diff(values, axis=0).reshape((n_out, *axis_values.shape[1:]))

    along_y = along(image, shape[0], offset[0])
    return along(along_y.T, shape[1], offset[1]).T


@pytest.mark.parametrize("ratio", [1.0, 2.0, 2.5, 0.7, 0.3])
@pytest.mark.parametrize("offset", [(0.0, 0.0), (0.37 * um, -1.21 * um)])
def test_matches_exact_box_integration(ratio, offset):
    # float64 round-off only: 1e-12 relative to the largest pixel value.
    rng = np.random.default_rng(1)
    image = rng.random((17, 22))
    grid = Grid((17, 22), D)
    pitch = ratio * D
    power = integrate_pixels(torch.from_numpy(image), grid, pitch, offset=offset)
    reference = box_integral_reference(image, D, pitch, tuple(power.shape), offset)
    assert np.abs(power.numpy() - reference).max() < 1e-12 * reference.max()
    # The covering sensor collects all the power.
    assert math.isclose(float(power.sum()), image.sum() * D * D, rel_tol=1e-12)


def test_supersampling_reference_for_pitch_2_5():
    # Second independent reference: split each cell into 20 x 20 sub-cells and bin their
    # centres into pixels; with pitch 2.5 d and no offset the pixel edges sit 0.75 d + k/2 d
    # from cell edges, i.e. on sub-cell edges (multiples of d/20): binning is exact.
    rng = np.random.default_rng(2)
    image = rng.random((12, 15))
    grid = Grid((12, 15), D)
    shape = (6, 7)
    power = integrate_pixels(torch.from_numpy(image), grid, 2.5 * D, shape=shape).numpy()
    s = 20
    fine = np.kron(image, np.ones((s, s))) * (D / s) ** 2
    ys = (np.arange(12 * s) - 12 // 2 * s - (s - 1) / 2) * D / s  # sub-cell centres
    xs = (np.arange(15 * s) - 15 // 2 * s - (s - 1) / 2) * D / s
    iy = np.floor(ys / (2.5 * D) + 0.5).astype(int) + shape[0] // 2
    ix = np.floor(xs / (2.5 * D) + 0.5).astype(int) + shape[1] // 2
    reference = np.zeros(shape)
    for a, row in zip(iy, fine, strict=True):
        if 0 <= a < shape[0]:
            np.add.at(reference[a], ix[(ix >= 0) & (ix < shape[1])], row[(ix >= 0) & (ix < shape[1])])
    assert np.abs(power - reference).max() < 1e-12 * reference.max()


def test_linear_ramp_integer_ratio_is_analytic():
    # A linear ramp I = 10 + 2 x/um sampled at cell centres. Pixels of pitch 2d shifted by
    # d/2 hold exactly two whole cells each, where the midpoint rule is exact for a linear
    # function: each pixel holds pitch^2 * I(pixel centre), to round-off.
    grid = Grid((8, 8), D)
    _, x = grid.axes()
    ramp = (10.0 + 2.0 * x / um)[None, :].expand(8, 8)
    power = integrate_pixels(ramp, grid, 2 * D, shape=(4, 4), offset=(0.5 * D, 0.5 * D))
    centres = (torch.arange(4, dtype=torch.float64) - 2) * 2 * D + 0.5 * D
    expected = (10.0 + 2.0 * centres / um)[None, :].expand(4, 4) * (2 * D) ** 2
    assert torch.allclose(power, expected, rtol=1e-12, atol=0)


def test_batch_dims_and_field_intensity():
    grid = Grid((5, 6), D)
    data = torch.randn(3, 5, 6, dtype=torch.complex128, generator=torch.Generator().manual_seed(0))
    irradiance = intensity(Field(data, grid, 500e-9))
    assert torch.allclose(irradiance, data.abs() ** 2)
    power = integrate_pixels(irradiance, grid, 1.5 * D)
    assert power.shape[0] == 3
    # A batch and its items alone are reduced in a different order (vectorised lanes differ
    # between CPUs): equal to float64 rounding of a sum of a few terms, not bit for bit.
    for i in range(3):
        single = integrate_pixels(irradiance[i], grid, 1.5 * D)
        assert torch.allclose(power[i], single, rtol=1e-12, atol=1e-14 * float(single.abs().max()))


def test_gradcheck_integrate_pixels():
    grid = Grid((6, 7), D)
    image = torch.rand(6, 7, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda im: integrate_pixels(im, grid, 1.7 * D, offset=(0.2 * um, 0.0)), (image,)
    )


def test_integrate_pixels_errors():
    grid = Grid(4, D)
    with pytest.raises(ValueError, match="pixel_pitch"):
        integrate_pixels(torch.ones(4, 4), grid, 0.0)
    with pytest.raises(ValueError, match="pixel_pitch"):
        integrate_pixels(torch.ones(4, 4), grid, (1 * um, -1 * um))
    with pytest.raises(TypeError, match="real"):
        integrate_pixels(torch.ones(4, 4, dtype=torch.complex64), grid, 1 * um)
    with pytest.raises(ValueError, match="grid shape"):
        integrate_pixels(torch.ones(4, 5), grid, 1 * um)


# -- sensor -------------------------------------------------------------------------


def test_camera_validation():
    with pytest.raises(ValueError, match="pixel_pitch"):
        Camera(pixel_pitch=-6.5 * um)
    for bits in (0, 33, 12.0, True):
        with pytest.raises(ValueError, match="bit_depth"):
            Camera(pixel_pitch=6.5 * um, bit_depth=bits)
    with pytest.raises(ValueError, match="quantum_efficiency"):
        Camera(pixel_pitch=6.5 * um, quantum_efficiency=1.2)
    with pytest.raises(ValueError, match="read_noise"):
        Camera(pixel_pitch=6.5 * um, read_noise=-1.0)
    with pytest.raises(ValueError, match="baseline"):
        Camera(pixel_pitch=6.5 * um, bit_depth=8, baseline=300)
    with pytest.raises(ValueError, match="gain"):
        Camera(pixel_pitch=6.5 * um, gain=0.0)
    with pytest.raises(ValueError, match="full_well"):
        Camera(pixel_pitch=6.5 * um, full_well=0.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        Camera(pixel_pitch=6.5 * um).gain = 2.0


def test_photon_scaling_and_negative_photons():
    camera = Camera(pixel_pitch=6.5 * um, quantum_efficiency=0.8)
    power = torch.rand(2, 10, 10, dtype=torch.float64)
    electrons = expected_electrons(power, camera, photons=5000.0)
    assert torch.allclose(electrons.sum(dim=(-2, -1)), torch.full((2,), 0.8 * 5000.0, dtype=torch.float64))
    assert torch.allclose(expected_electrons(power, camera, photons_per_unit=7.0), 0.8 * 7.0 * power)
    with pytest.raises(ValueError, match="photons"):
        expected_electrons(power, camera, photons=-1.0)
    with pytest.raises(ValueError, match="photons_per_unit"):
        expected_electrons(power, camera, photons_per_unit=-1.0)


N_PIXELS = 200 * 200


def test_poisson_statistics():
    # Mean 100 e-: the sample mean has sd sqrt(100/N) = 0.05 and the sample variance sd
    # sqrt((2 mu^2 + mu)/N) = 0.71 for N = 40000; 5 sd tolerances (a seeded, deterministic draw).
    camera = Camera(pixel_pitch=6.5 * um)
    rate = torch.full((200, 200), 100.0, dtype=torch.float64)
    electrons = sample_electrons(rate, camera, generator=torch.Generator().manual_seed(3))
    assert torch.equal(electrons, electrons.round())  # counts
    assert abs(float(electrons.mean()) - 100.0) < 5 * 0.05
    assert abs(float(electrons.var()) - 100.0) < 5 * math.sqrt((2 * 100.0**2 + 100.0) / N_PIXELS)


def test_read_noise_statistics():
    # Gaussian, sigma 3 e-: the sample sd has sd sigma / sqrt(2N) = 0.0106; 5 sd tolerance.
    camera = Camera(pixel_pitch=6.5 * um, read_noise=3.0)
    zero = torch.zeros(200, 200, dtype=torch.float64)
    electrons = sample_electrons(zero, camera, generator=7, shot_noise=False)
    assert abs(float(electrons.mean())) < 5 * 3.0 / math.sqrt(N_PIXELS)
    assert abs(float(electrons.std()) - 3.0) < 5 * 3.0 / math.sqrt(2 * N_PIXELS)


def test_gain_baseline_and_adu_statistics():
    # ADU = gain * e- + baseline: mean 2 * 50 + 100, variance gain^2 (mu + sigma_r^2)
    # (+ 1/12 from rounding) = 4 * 54 + 1/12; 5 sd tolerances as above.
    camera = Camera(pixel_pitch=6.5 * um, read_noise=2.0, gain=2.0, baseline=100.0, bit_depth=12)
    power = torch.full((200, 200), 50.0, dtype=torch.float64)
    adu = simulate_sensor(power, camera, generator=11)
    assert torch.equal(adu, adu.round())
    assert abs(float(adu.mean()) - 200.0) < 5 * math.sqrt(4 * 54 / N_PIXELS)
    variance = 4 * 54 + 1 / 12
    assert abs(float(adu.var()) - variance) < 5 * variance * math.sqrt(2 / N_PIXELS)


def test_saturation_and_full_well():
    camera = Camera(pixel_pitch=6.5 * um, bit_depth=8, gain=1.0)
    bright = torch.full((4, 4), 1e6, dtype=torch.float64)
    assert torch.equal(
        simulate_sensor(bright, camera, generator=0), torch.full((4, 4), 255.0, dtype=torch.float64)
    )
    well = Camera(pixel_pitch=6.5 * um, bit_depth=16, full_well=1000.0)
    assert float(simulate_sensor(bright, well, generator=0).max()) == 1000.0
    dark = Camera(pixel_pitch=6.5 * um, read_noise=5.0)
    assert float(simulate_sensor(torch.zeros(50, 50), dark, generator=0).min()) == 0.0  # clipped at 0 ADU


def test_same_seed_same_image_different_seed_different_image():
    camera = Camera(pixel_pitch=6.5 * um, read_noise=1.5, gain=0.5)
    power = torch.rand(32, 32, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    a = simulate_sensor(power, camera, photons=1e5, generator=torch.Generator().manual_seed(42))
    b = simulate_sensor(power, camera, photons=1e5, generator=torch.Generator().manual_seed(42))
    c = simulate_sensor(power, camera, photons=1e5, generator=torch.Generator().manual_seed(43))
    assert torch.equal(a, b)
    assert not torch.equal(a, c)
    assert torch.equal(
        a, simulate_sensor(power, camera, photons=1e5, generator=42)
    )  # int seed = Generator seed


def test_noise_needs_an_explicit_generator():
    camera = Camera(pixel_pitch=6.5 * um)
    with pytest.raises(ValueError, match="generator"):
        simulate_sensor(torch.ones(4, 4), camera)
    # Noise-free images need none.
    clean = simulate_sensor(torch.ones(4, 4), camera, shot_noise=False, read_noise=False)
    assert torch.equal(clean, torch.ones(4, 4))


def test_noise_free_path_is_differentiable():
    camera = Camera(pixel_pitch=6.5 * um, quantum_efficiency=0.7, gain=1.3, baseline=10.0)
    power = torch.rand(3, 4, dtype=torch.float64, requires_grad=True)

    def clean(p):
        return simulate_sensor(
            p,
            camera,
            photons_per_unit=50.0,
            shot_noise=False,
            read_noise=False,
            quantize=False,
            saturate=False,
        )

    assert torch.allclose(clean(power), 1.3 * 0.7 * 50.0 * power + 10.0)
    assert torch.autograd.gradcheck(clean, (power,))
    assert torch.equal(digitize(torch.tensor([1.4, 1.6, -3.0]), camera), torch.tensor([12.0, 12.0, 6.0]))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    grid = Grid((20, 24), D)
    image = torch.rand(2, 20, 24, dtype=torch.float64)
    cpu = integrate_pixels(image, grid, 2.5 * D, offset=(0.3 * um, 0.0))
    gpu = integrate_pixels(image.cuda(), grid, 2.5 * D, offset=(0.3 * um, 0.0))
    assert torch.allclose(gpu.cpu(), cpu, rtol=1e-12, atol=0)
    camera = Camera(pixel_pitch=2.5 * um, read_noise=1.0)
    counts = simulate_sensor(gpu, camera, photons=1e4, generator=5)
    assert counts.device.type == "cuda" and counts.shape == cpu.shape


def test_capture_chains_the_stages():
    grid = Grid((9, 10), D)
    data = torch.randn(9, 10, dtype=torch.complex128, generator=torch.Generator().manual_seed(4))
    field = Field(data, grid, 500e-9)
    camera = Camera(pixel_pitch=2.5 * um, shape=(3, 3), read_noise=1.0, gain=2.0)
    counts = capture(field, camera, offset=(0.5 * um, 0.0), photons=1e4, generator=9)
    # The same stages called one by one (the same code path, so the same seeded draw bit for bit;
    # |U|^2 as intensity() computes it, not as abs()**2, which rounds differently).
    power = integrate_pixels(intensity(field), grid, 2.5 * um, shape=(3, 3), offset=(0.5 * um, 0.0))
    assert counts.shape == (3, 3)
    assert torch.equal(counts, simulate_sensor(power, camera, photons=1e4, generator=9))
