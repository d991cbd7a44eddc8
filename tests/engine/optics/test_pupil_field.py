"""Back-focal-plane field of a point source: cut-off, defocus phase, models, normalisation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lfm_studio.engine.errors import SamplingWarning
from lfm_studio.engine.optics.debye import debye_integral
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.objective import ObjectiveLens, image_point
from lfm_studio.engine.optics.pupil_field import pupil_field
from lfm_studio.engine.units import mm, nm, um

WAVELENGTH = 500 * nm
K = 2 * math.pi / WAVELENGTH


def water_40x() -> ObjectiveLens:
    return ObjectiveLens(40, 1.0, 1.33, 200 * mm)  # f_obj = 5 mm, pupil radius 5 mm


def pupil_grid(obj: ObjectiveLens, n: int = 256) -> Grid:
    return Grid(n, 2.1 * obj.pupil_radius / n)


def sin_theta(obj: ObjectiveLens, grid: Grid) -> np.ndarray:
    return np.sqrt(grid.radius_squared().numpy()) / (obj.immersion_index * obj.focal_length)


def test_field_is_cut_at_the_numerical_aperture():
    obj = water_40x()
    grid = pupil_grid(obj, 128)
    amplitude = pupil_field(obj, grid, WAVELENGTH, 1 * um, dtype=torch.complex128).data.abs().numpy()
    rho = np.sqrt(grid.radius_squared().numpy())
    radius = obj.pupil_radius
    assert (amplitude[rho > radius * (1 + 1e-9)] == 0).all()
    assert (amplitude[rho <= radius] > 0).all()
    assert (rho <= radius).sum() > 0.6 * rho.size  # the pupil fills most of the window


@pytest.mark.parametrize("z", [-12 * um, 3 * um, 20 * um])
def test_defocus_phase_is_n_k_z_cos_theta(z):
    # arg A(z) - arg A(0) = n k z (cos(theta) - 1) at every sample inside the pupil (the
    # constant n k z is dropped). Reference: the direct float64 form, round-off ~1e-13 rad
    # for phases up to ~400 rad; wrapped to (-pi, pi].
    obj = water_40x()
    grid = pupil_grid(obj, 256)  # 20 um of defocus needs <= 55 um pupil sampling
    a_z = pupil_field(obj, grid, WAVELENGTH, z, dtype=torch.complex128).data.numpy()
    a_0 = pupil_field(obj, grid, WAVELENGTH, 0.0, dtype=torch.complex128).data.numpy()
    s = sin_theta(obj, grid)
    inside = s <= 1.0 / 1.33
    expected = 1.33 * K * z * (np.sqrt(1 - s[inside] ** 2) - 1)
    difference = np.angle(a_z[inside] * np.conj(a_0[inside]) * np.exp(-1j * expected))
    assert np.abs(difference).max() < 1e-9
    assert np.abs(expected).max() > 10  # many radians: the check is not trivial


def test_aplanatic_amplitude_and_power():
    # |A| = (1/sqrt(cos theta)) / (sqrt(4 pi) n f): uniform energy per solid angle, total
    # (1 - cos alpha)/2 of a unit-power emitter. The hard-edged pixelated disk misses
    # O(R^(2/3)) samples (Gauss circle problem): relative error <~ R_px^(-4/3)/cos(alpha)
    # = 2.5e-3 at R = 122 px (measured -2.6e-4).
    obj = water_40x()
    grid = pupil_grid(obj)
    field = pupil_field(obj, grid, WAVELENGTH, 0.0, dtype=torch.complex128)
    s = sin_theta(obj, grid)
    inside = s <= 1.0 / 1.33
    expected = (1 - s[inside] ** 2) ** -0.25 / (math.sqrt(4 * math.pi) * 1.33 * obj.focal_length)
    assert np.abs(field.data.abs().numpy()[inside] / expected - 1).max() < 1e-13
    alpha = obj.half_angle
    r_px = obj.pupil_radius / grid.dx
    assert abs(float(field.power()) / ((1 - math.cos(alpha)) / 2) - 1) < r_px ** (-4 / 3) / math.cos(alpha)
    assert field.refractive_index == 1.0


def test_tube_lens_fourier_transform_equals_image_side_debye_field():
    # The tube lens (Fourier lens, d = f_tube) maps the pupil field A to
    # U(x') = 1/(j lambda f_t) sum A exp(-j 2 pi rho.x' / (lambda f_t)) dA, which must be
    # the image-side Debye field U_obj(-x'/M)/M, with its constant, inversion, defocus and
    # tilt signs. Direct DFT sum at a few points; the pixelated rim limits agreement to
    # ~R_px^(-4/3) = 1.7e-3 of the peak (measured 3e-4 at 244 px, 1e-3 at 122 px).
    obj = water_40x()
    grid = pupil_grid(obj)
    z = torch.tensor([0.0, 1.5 * um], dtype=torch.float64)
    position = (0.4 * um, -0.2 * um)
    pupil = pupil_field(obj, grid, WAVELENGTH, z, position=position, dtype=torch.complex128).data
    f_t, m = 200 * mm, 40
    xi = torch.tensor([-8.0, -5.0, 0.0, 3.0, 6.0, 10.0], dtype=torch.float64) * um
    yi = torch.tensor([4.0, 0.0, 0.0, -2.0, 5.0, 1.0], dtype=torch.float64) * um
    ys, xs = grid.axes()
    image = torch.stack(
        [
            (pupil * torch.exp(-2j * math.pi * (xs[None, :] * a + ys[:, None] * b) / (WAVELENGTH * f_t))).sum(
                (-2, -1)
            )
            for a, b in zip(xi, yi, strict=True)
        ],
        dim=-1,
    ) * (grid.pixel_area / (1j * WAVELENGTH * f_t))
    r = torch.sqrt((-xi / m - position[0]) ** 2 + (-yi / m - position[1]) ** 2)
    debye = debye_integral(obj, WAVELENGTH, r, z) / m
    peak = abs(complex(debye_integral(obj, WAVELENGTH, torch.zeros(1, dtype=torch.float64), 0.0)[0])) / m
    assert (image - debye).abs().max() < 5e-3 * peak
    assert debye.abs().median() > 0.05 * peak  # the points sample the PSF, not only its tails


def test_debye_and_paraxial_agree_to_expected_order_at_low_na():
    # At the rim s = NA/n: amplitude 1/sqrt(cos) - 1 ~ s^2/4, phase n k z (cos - 1 + s^2/2)
    # ~ n k z s^4/8. The largest difference must lie under their sum and be of that order.
    obj = ObjectiveLens(20, 0.1, 1.0, 200 * mm)  # f = 10 mm, pupil radius 1 mm
    grid = pupil_grid(obj, 128)
    z = 40 * um
    debye = pupil_field(obj, grid, WAVELENGTH, z, dtype=torch.complex128).data
    paraxial = pupil_field(obj, grid, WAVELENGTH, z, model="paraxial", dtype=torch.complex128).data
    scale = 1 / (math.sqrt(4 * math.pi) * obj.focal_length)
    difference = float((debye - paraxial).abs().max()) / scale
    s = 0.1
    cos_a = math.sqrt(1 - s * s)
    amplitude_error = 1 / math.sqrt(cos_a) - 1
    phase_error = K * z * abs(cos_a - 1 + s * s / 2)
    assert amplitude_error == pytest.approx(s * s / 4, rel=0.02)
    assert phase_error == pytest.approx(K * z * s**4 / 8, rel=0.02)
    assert 0.5 * max(amplitude_error, phase_error) < difference <= amplitude_error + phase_error + 1e-12


def test_paraxial_focus_lands_at_image_point():
    # Paraxial pupil phase -k z rho^2 / (2 n f^2) is a lens of power z/(n f^2) at the tube
    # lens's front focal plane; Newton's equation puts the focus f_t^2 z/(n f^2) = M^2 z/n
    # before the image plane: exactly image_point's axial coordinate.
    obj = water_40x()
    grid = pupil_grid(obj, 64)
    z = 2 * um
    field = pupil_field(obj, grid, WAVELENGTH, z, model="paraxial", dtype=torch.complex128).data
    i = 32 + 3  # a sample 3 pixels off axis, phase well below pi
    rho = 3 * grid.dx
    phase = float(torch.angle(field[32, i]))
    power = -phase / (K * rho**2 / 2)  # 1/F in 1/m
    displacement = (200 * mm) ** 2 * power
    assert displacement == pytest.approx(image_point(obj, (0.0, 0.0, z))[2], rel=1e-9)


def test_gradcheck_wrt_z():
    obj = water_40x()
    grid = Grid(6, obj.pupil_radius / 2.5)

    def field(z):
        return pupil_field(obj, grid, WAVELENGTH, z * 1e-6, dtype=torch.complex128).data * 1e-3

    z = torch.tensor([-0.2, 0.3], dtype=torch.float64, requires_grad=True)  # sampled: |z| < 0.55 um here
    assert torch.autograd.gradcheck(field, (z,))


def test_sampling_warnings():
    obj = water_40x()
    with pytest.warns(SamplingWarning, match="pupil radius"):
        pupil_field(obj, Grid(32, obj.pupil_radius / 20), WAVELENGTH, 0.0)
    with pytest.warns(SamplingWarning, match="undersampled"):
        pupil_field(obj, pupil_grid(obj, 64), WAVELENGTH, 100 * um)


def test_bad_model():
    obj = water_40x()
    with pytest.raises(ValueError, match="model"):
        pupil_field(obj, pupil_grid(obj, 16), WAVELENGTH, 0.0, model="fresnel")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    obj = water_40x()
    grid = pupil_grid(obj, 64)
    z = torch.tensor([-2.0, 3.0], dtype=torch.float64) * um
    cpu = pupil_field(obj, grid, WAVELENGTH, z, position=(0.3 * um, 0.0), dtype=torch.complex128)
    gpu = pupil_field(
        obj, grid, WAVELENGTH, z.cuda(), position=(0.3 * um, 0.0), dtype=torch.complex128, device="cuda"
    )
    assert torch.allclose(gpu.data.cpu(), cpu.data, rtol=0, atol=1e-12 * cpu.data.abs().max())


def test_center_selects_a_window_of_the_full_pupil():
    # A small grid centred on a pupil point gives the crop of the full-grid field there
    # (coordinates differ only by float rounding: 1e-12 of the peak).
    obj = water_40x()
    full_grid = pupil_grid(obj, 64)
    d = full_grid.dx
    z = torch.tensor([0.0, 2 * um], dtype=torch.float64)
    options = {"position": (0.2 * um, -0.1 * um), "dtype": torch.complex128}
    full = pupil_field(obj, full_grid, WAVELENGTH, z, **options).data
    window = pupil_field(
        obj, Grid((8, 6), d), WAVELENGTH, z, center=(10 * d, -20 * d), check_sampling=False, **options
    ).data
    crop = full[:, 32 - 20 - 4 : 32 - 20 + 4, 32 + 10 - 3 : 32 + 10 + 3]
    assert torch.allclose(window, crop, rtol=0, atol=1e-12 * full.abs().max())
