"""Debye integral (thesis eq. 3.14) against closed forms, and its numerics.

Error budget shared by the closed-form tests: the Gauss-Legendre order defaults to
``ceil(Phi/2) + 64`` for a total integrand phase ``Phi``; the convergence study
(test_quadrature_convergence below, and the module docstring) puts the quadrature
error under 1e-12 of the peak from ``ceil(Phi/3) + 48`` nodes on; float64 round-off in
the matrix product adds ~1e-15. Closed forms are therefore checked to 1e-12.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.integrate as si
import scipy.optimize as so
import scipy.special as sp
import torch

from lfm_studio.engine.errors import SamplingWarning
from lfm_studio.engine.optics.debye import (
    debye_integral,
    debye_psf,
    minimum_quadrature_order,
    phase_excursion,
    quadrature_order,
)
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.units import mm, nm, um

WAVELENGTH = 500 * nm
K = 2 * math.pi / WAVELENGTH
APERTURES = [
    (0.3, 1.0),
    (0.95, 1.0),
    (1.2, 1.33),
    (1.329, 1.33),
    (1.4, 1.518),
]  # 1.329/1.33: alpha = 87.5 deg


def objective(na: float, n: float) -> ObjectiveLens:
    return ObjectiveLens(40, na, n, 200 * mm)


def on_axis(obj: ObjectiveLens, z: torch.Tensor, apodization: str = "aplanatic") -> torch.Tensor:
    return debye_integral(obj, WAVELENGTH, torch.zeros(1, dtype=torch.float64), z, apodization=apodization)[
        ..., 0
    ]


@pytest.mark.parametrize(("na", "n"), APERTURES)
def test_flat_pupil_gives_sinc_squared_on_axis(na, n):
    # P = 1: integral of exp(-j u sin^2(theta/2) / (2 sin^2(alpha/2))) sin(theta) is exactly
    # 4 sin^2(alpha/2) exp(-ju/4) sin(u/4)/(u/4) at any aperture -> I(u)/I(0) = sinc^2(u/4).
    obj = objective(na, n)
    alpha = obj.half_angle
    u = torch.linspace(-80.0, 80.0, 321, dtype=torch.float64)
    z = u / (4 * K * n * math.sin(alpha / 2) ** 2)
    intensity = on_axis(obj, z, "flat").abs() ** 2
    normalised = (intensity / intensity[160]).numpy()
    assert np.abs(normalised - np.sinc(u.numpy() / (4 * np.pi)) ** 2).max() < 1e-12


@pytest.mark.parametrize(("na", "n"), APERTURES)
def test_cos_pupil_gives_airy_pattern_in_focus(na, n):
    # P = cos(theta): with s = sin(theta), integral_0^sin(alpha) J0(v s / sin(alpha)) s ds
    # = sin^2(alpha) J1(v)/v exactly, so I/I(0) = [2 J1(v)/v]^2 at ANY aperture angle.
    obj = objective(na, n)
    v = torch.linspace(0.0, 40.0, 401, dtype=torch.float64)
    r = v / (K * na)
    intensity = debye_integral(obj, WAVELENGTH, r, 0.0, apodization="cos").abs() ** 2
    vn = v.numpy()
    airy = np.ones_like(vn)
    airy[1:] = (2 * sp.j1(vn[1:]) / vn[1:]) ** 2
    assert np.abs((intensity / intensity[0]).numpy() - airy).max() < 1e-12


@pytest.mark.parametrize(("na", "n"), APERTURES)
def test_absolute_normalisation_on_axis(na, n):
    # U(0, 0) = -j sqrt(pi) n / lambda * integral_0^alpha sqrt(cos) sin = (2/3)(1 - cos^1.5 alpha).
    obj = objective(na, n)
    alpha = obj.half_angle
    expected = math.sqrt(math.pi) * n / WAVELENGTH * 2.0 / 3.0 * (1.0 - math.cos(alpha) ** 1.5)
    value = complex(on_axis(obj, torch.tensor(0.0, dtype=torch.float64)))
    assert abs(value - (-1j * expected)) < 1e-12 * expected


@pytest.mark.parametrize("na", [0.1, 0.3])
def test_aplanatic_fwhm_low_na_is_airy(na):
    # Airy FWHM = 2 * 1.616340 / (k NA) = 0.514497 lambda/NA; the aplanatic sqrt(cos)
    # weighting narrows it by ~0.023 sin^2(alpha) (measured 2.3e-4 at NA 0.1, 2.1e-3 at
    # 0.3), so the tolerance is 0.03 sin^2(alpha).
    obj = objective(na, 1.0)
    peak = abs(complex(on_axis(obj, torch.tensor(0.0, dtype=torch.float64)))) ** 2

    def half(r):
        value = debye_integral(obj, WAVELENGTH, torch.tensor([r], dtype=torch.float64), 0.0)
        return float(value.abs() ** 2) / peak - 0.5

    fwhm = 2 * so.brentq(half, 0.1 * WAVELENGTH / na, 0.6 * WAVELENGTH / na, xtol=1e-15)
    assert abs(fwhm * na / WAVELENGTH / 0.514497 - 1) < 0.03 * na**2


@pytest.mark.filterwarnings("ignore::scipy.integrate.IntegrationWarning")
def test_aplanatic_fwhm_high_na_matches_adaptive_reference():
    # NA 1.2 in water: FWHM = 0.49768 lambda/NA (narrower than Airy's 0.5145). Reference:
    # scipy's adaptive quad + scipy j0, root by brentq to 1e-16 m; agreement 1e-9 relative
    # (measured 5e-16: both are quadrature-converged to ~1e-13).
    na, n = 1.2, 1.33
    obj = objective(na, n)
    alpha = obj.half_angle

    def reference(r):
        def integrand(t):
            return math.sqrt(math.cos(t)) * sp.j0(K * n * r * math.sin(t)) * math.sin(t)

        return si.quad(integrand, 0.0, alpha, epsabs=0.0, epsrel=1e-13, limit=200)[0]

    ref0 = reference(0.0)
    ref_half = so.brentq(
        lambda r: (reference(r) / ref0) ** 2 - 0.5, 0.1 * WAVELENGTH, 0.5 * WAVELENGTH, xtol=1e-16
    )
    peak = abs(complex(on_axis(obj, torch.tensor(0.0, dtype=torch.float64)))) ** 2
    ours = so.brentq(
        lambda r: (
            float(debye_integral(obj, WAVELENGTH, torch.tensor([r], dtype=torch.float64), 0.0).abs() ** 2)
            / peak
            - 0.5
        ),
        0.1 * WAVELENGTH,
        0.5 * WAVELENGTH,
        xtol=1e-16,
    )
    assert abs(ours / ref_half - 1) < 1e-9
    assert abs(2 * ours * na / WAVELENGTH - 0.49768) < 1e-5


def test_aplanatic_intensity_is_symmetric_in_z():
    # Real P: U(-u) = conj(U(u)), so |U|^2 is even in z (round-off level, 1e-12 of the peak).
    obj = objective(1.2, 1.33)
    grid = Grid((9, 11), 80 * nm)
    z = torch.tensor([0.4, 1.0, 2.5], dtype=torch.float64) * um
    plus = debye_psf(obj, grid, WAVELENGTH, z, dtype=torch.complex128).intensity()
    minus = debye_psf(obj, grid, WAVELENGTH, -z, dtype=torch.complex128).intensity()
    assert (plus - minus).abs().max() < 1e-12 * plus.max()
    # ...while the field itself is not even in z (the test is not a tautology).
    field_plus = debye_psf(obj, grid, WAVELENGTH, z, dtype=torch.complex128).data
    field_minus = debye_psf(obj, grid, WAVELENGTH, -z, dtype=torch.complex128).data
    assert (field_plus - field_minus).abs().max() > 0.1 * field_plus.abs().max()


def test_quadrature_convergence():
    # NA 1.0 water, r <= 15 um, |z| <= 20 um: Phi = 302 rad. Reference with twice the
    # default order. Measured: Phi/6 = 50 nodes 2.7e-2, Phi/4 = 75 nodes 1.6e-2,
    # minimum order 149 nodes 1.3e-15, default 216 nodes 1.2e-15 (of the peak).
    obj = objective(1.0, 1.33)
    r = torch.linspace(0.0, 15 * um, 60, dtype=torch.float64)
    z = torch.linspace(-20 * um, 20 * um, 5, dtype=torch.float64)
    phi = phase_excursion(obj, WAVELENGTH, 15 * um, 20 * um)
    reference = debye_integral(obj, WAVELENGTH, r, z, n_quadrature=2 * quadrature_order(phi))
    peak = on_axis(obj, torch.tensor(0.0, dtype=torch.float64)).abs()

    def error(order):
        return float(
            (debye_integral(obj, WAVELENGTH, r, z, n_quadrature=order) - reference).abs().max() / peak
        )

    assert error(minimum_quadrature_order(phi)) < 1e-12
    assert float((debye_integral(obj, WAVELENGTH, r, z) - reference).abs().max() / peak) < 1e-12
    with pytest.warns(SamplingWarning, match="n_quadrature"):
        assert error(int(phi / 6)) > 1e-3


def test_depth_batch_equals_single_depths():
    obj = objective(0.8, 1.0)
    grid = Grid((6, 7), 100 * nm)
    z = torch.tensor([-1.0, 0.0, 2.0], dtype=torch.float64) * um
    batch = debye_psf(obj, grid, WAVELENGTH, z, dtype=torch.complex128, n_quadrature=96)
    assert batch.data.shape == (3, 6, 7)
    for i in range(3):
        single = debye_psf(obj, grid, WAVELENGTH, float(z[i]), dtype=torch.complex128, n_quadrature=96)
        assert single.data.shape == (6, 7)
        assert torch.allclose(batch.data[i], single.data, rtol=0, atol=1e-12 * single.data.abs().max())


def test_grid_values_equal_radial_integral_at_each_radius():
    # Off-axis source: every grid sample equals the radial integral at its own distance.
    obj = objective(1.2, 1.33)
    grid = Grid((5, 8), 70 * nm)
    position = (0.11 * um, -0.05 * um)
    field = debye_psf(obj, grid, WAVELENGTH, 0.3 * um, position=position, dtype=torch.complex128)
    y, x = grid.axes()
    r = torch.sqrt((x[None, :] - position[0]) ** 2 + (y[:, None] - position[1]) ** 2).reshape(-1)
    direct = debye_integral(obj, WAVELENGTH, r, 0.3 * um).reshape(5, 8)
    assert torch.allclose(field.data, direct, rtol=0, atol=1e-13 * direct.abs().max())
    assert field.refractive_index == 1.33


def test_image_side_is_inverted_magnified_and_power_preserving():
    # U_img(x') = U_obj(-x'/M) / M: the image of a source at +x0 peaks at -M x0, and the
    # power over corresponding grids (spacing x M) is equal to round-off.
    obj = objective(0.8, 1.0)
    m = 40
    d = 60 * nm
    obj_grid, img_grid = Grid(33, d), Grid(33, d * m)
    position = (3 * d, -2 * d)
    img = debye_psf(
        obj, img_grid, WAVELENGTH, 0.0, position=position, image_side=True, dtype=torch.complex128
    )
    peak = np.unravel_index(int(img.intensity().argmax()), img_grid.shape)
    assert (peak[0] - 16, peak[1] - 16) == (2, -3)  # (y, x) index offsets of (-M y0, -M x0) / (M d)
    src = debye_psf(
        obj, obj_grid, WAVELENGTH, 0.0, position=(-position[0], -position[1]), dtype=torch.complex128
    )
    assert torch.allclose(img.data * m, src.data, rtol=0, atol=1e-13 * src.data.abs().max())
    assert math.isclose(float(img.power()), float(src.power()), rel_tol=1e-12)
    assert img.refractive_index == 1.0


def test_complex64_matches_complex128():
    # Everything is computed in float64; only the final cast rounds (2^-24 relative).
    obj = objective(1.2, 1.33)
    grid = Grid(16, 50 * nm)
    z = torch.tensor([0.0, 1.5 * um])
    f64 = debye_psf(obj, grid, WAVELENGTH, z, dtype=torch.complex128).data
    f32 = debye_psf(obj, grid, WAVELENGTH, z, dtype=torch.complex64).data
    assert f32.dtype == torch.complex64
    assert (f32.to(torch.complex128) - f64).abs().max() < 1e-7 * f64.abs().max()


@pytest.mark.parametrize("radial_sampling", ["exact", 4])
def test_gradcheck_wrt_z_and_na(radial_sampling):
    grid = Grid((2, 3), 120 * nm)

    def psf(z, na):
        obj = ObjectiveLens(40, na, 1.33, 200 * mm)
        options = {"dtype": torch.complex128, "n_quadrature": 64, "radial_sampling": radial_sampling}
        return debye_psf(obj, grid, WAVELENGTH, z, **options).data

    z = torch.tensor([-0.4e-6, 0.7e-6], dtype=torch.float64, requires_grad=True)
    na = torch.tensor(1.1, dtype=torch.float64, requires_grad=True)
    # Scale to O(1) inputs so the finite-difference steps are sensible; fast mode checks
    # random projections of the Jacobian (the full check took 4.5 s on the table path).
    assert torch.autograd.gradcheck(
        lambda zs, a: psf(zs * 1e-6, a) * 1e-6, (z * 1e6, na), eps=1e-6, atol=1e-6, fast_mode=True
    )


@pytest.mark.parametrize("radial_sampling", ["exact", 4, "auto"])
def test_tensor_wavelength_equals_the_float_path_and_passes_gradcheck(radial_sampling):
    """A 0-d tensor wavelength gives the float path's field (the quadrature and radial table are
    planned from its value) and a gradient that gradcheck confirms."""
    grid = Grid((3, 4), 120 * nm)
    obj = ObjectiveLens(40, 1.1, 1.33, 200 * mm)
    z = torch.tensor([-0.4e-6, 0.7e-6], dtype=torch.float64)
    options = {"dtype": torch.complex128, "radial_sampling": radial_sampling, "image_side": True}
    plain = debye_psf(obj, grid, WAVELENGTH, z, **options).data
    tensor = debye_psf(obj, grid, torch.tensor(WAVELENGTH, dtype=torch.float64), z, **options)
    assert isinstance(tensor.wavelength, float) and tensor.wavelength == WAVELENGTH
    assert (tensor.data - plain).abs().max() <= 1e-13 * plain.abs().max()

    def psf(lam_um):
        return debye_psf(obj, grid, lam_um * um, z, n_quadrature=64, **options).data * 1e-6

    lam = torch.tensor(WAVELENGTH / um, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(psf, (lam,), eps=1e-6, atol=1e-6)


def test_radial_derivative_matches_finite_differences():
    # Central differences with step 1e-11 m: truncation ~(k n h)^2/6 ~ 1e-8, round-off
    # ~1e-16/1e-11 * r-scale; 1e-7 of max |dU/dr|.
    obj = objective(1.2, 1.33)
    r = torch.linspace(0.0, 2 * um, 40, dtype=torch.float64)
    z = torch.tensor([0.0, 0.8 * um], dtype=torch.float64)
    values, slopes = debye_integral(obj, WAVELENGTH, r, z, derivative=True)
    assert torch.equal(values, debye_integral(obj, WAVELENGTH, r, z))
    h = 1e-11
    numeric = (debye_integral(obj, WAVELENGTH, r + h, z) - debye_integral(obj, WAVELENGTH, r - h, z)) / (
        2 * h
    )
    assert (numeric - slopes).abs().max() < 1e-7 * slopes.abs().max()


@pytest.mark.parametrize("oversampling", [2, 8])
def test_radial_table_interpolation_error_is_within_its_bound(oversampling):
    # Cubic Hermite on a table of step h with exact derivatives: error <= h^4/384 max|U^(4)|
    # <= (k NA h)^4/384 of the peak (band limit k NA). Measured ~1/8 of the bound; it must
    # also be clearly non-zero (the test would catch a silent fall-back to the exact path).
    na = 1.2
    obj = objective(na, 1.33)
    spacing = WAVELENGTH / (4 * na)  # Nyquist for the field
    grid = Grid(32, spacing)
    z = torch.tensor([0.0, 0.7 * um], dtype=torch.float64)
    position = (0.13 * um, 0.05 * um)
    exact = debye_psf(
        obj, grid, WAVELENGTH, z, position=position, radial_sampling="exact", dtype=torch.complex128
    )
    table = debye_psf(
        obj, grid, WAVELENGTH, z, position=position, radial_sampling=oversampling, dtype=torch.complex128
    )
    peak = float(exact.data.abs().max())
    bound = (K * na * spacing / oversampling) ** 4 / 384
    error = float((table.data - exact.data).abs().max()) / peak
    assert bound / 100 < error < bound


def test_auto_radial_sampling():
    # Small centred grid: few distinct radii -> the exact path (bit-identical). Off-axis
    # grid: table of step lambda/(4 NA)/32 -> error <= 1.5e-8 of the peak.
    obj = objective(1.2, 1.33)
    centred = Grid(16, 60 * nm)
    auto = debye_psf(obj, centred, WAVELENGTH, 0.5 * um, dtype=torch.complex128)
    exact = debye_psf(obj, centred, WAVELENGTH, 0.5 * um, radial_sampling="exact", dtype=torch.complex128)
    assert torch.equal(auto.data, exact.data)
    grid = Grid(48, 60 * nm)
    position = (0.013 * um, 0.021 * um)
    options = {"position": position, "dtype": torch.complex128}
    exact = debye_psf(obj, grid, WAVELENGTH, 0.5 * um, radial_sampling="exact", **options)
    auto = debye_psf(obj, grid, WAVELENGTH, 0.5 * um, **options)
    difference = float((auto.data - exact.data).abs().max()) / float(exact.data.abs().max())
    assert 0 < difference < 1.5e-8


def test_bad_inputs():
    obj = objective(0.5, 1.0)
    grid = Grid(4, 100 * nm)
    with pytest.raises(ValueError, match="apodization"):
        debye_psf(obj, grid, WAVELENGTH, 0.0, apodization="gauss")
    with pytest.raises(ValueError, match="1-D tensor of depths"):
        debye_psf(obj, grid, WAVELENGTH, torch.zeros(2, 2))
    with pytest.raises(ValueError, match="wavelength"):
        debye_psf(obj, grid, -WAVELENGTH, 0.0)
    with pytest.raises(ValueError, match="NaN"):
        debye_psf(obj, grid, WAVELENGTH, torch.tensor([float("nan")]))
    with pytest.raises(ValueError, match="radial_sampling"):
        debye_psf(obj, grid, WAVELENGTH, 0.0, radial_sampling=0)
    with pytest.raises(ValueError, match="n_quadrature"):
        debye_psf(obj, grid, WAVELENGTH, 0.0, n_quadrature=64.0)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    obj = objective(1.2, 1.33)
    grid = Grid(24, 60 * nm)
    z = torch.tensor([-1.0, 0.0, 1.0], dtype=torch.float64) * um
    cpu = debye_psf(obj, grid, WAVELENGTH, z, dtype=torch.complex128)
    gpu = debye_psf(obj, grid, WAVELENGTH, z.cuda(), dtype=torch.complex128, device="cuda")
    assert gpu.data.device.type == "cuda"
    assert torch.allclose(gpu.data.cpu(), cpu.data, rtol=0, atol=1e-12 * cpu.data.abs().max())
