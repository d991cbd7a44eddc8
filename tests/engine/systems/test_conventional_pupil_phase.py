"""A rotationally symmetric Zernike phase on a conventional LFM's pupil (``pupil_zernike_waves``, a
design's ``pupil_phase`` with m = 0 terms): it enters the Debye integrand at the normalised pupil
radius rho = sin(theta) / sin(alpha). Zero terms change nothing (bit for bit), Noll 4 equals the
closed-form depth shift, other terms are refused by name, and the coefficient's gradient through
the patterns equals a central difference of the float path.

Pattern system as in test_conventional_gradients: 10x/0.3 air objective, 50 um pitch square
lenslets (40 um clear aperture) of 1 mm focal length, camera 1 mm behind, 5 pixels and 3 voxels
per lenslet, 3 x 3 lenslets, two depths, float64.
"""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from lfm_studio.engine.optics import debye as debye_module
from lfm_studio.engine.optics.debye import debye_integral, debye_psf
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.optics.pupil_field import pupil_field
from lfm_studio.engine.systems.conventional_patterns import conventional_patterns
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem
from lfm_studio.engine.units import mm, nm, um

F64 = torch.float64
WAVELENGTH = 525 * nm
DEPTHS = (0.0, 6 * um)
SYSTEM = ConventionalLFMSystem(
    ObjectiveLens(10.0, 0.3, 1.0, 200 * mm), 50 * um, 1 * mm, "square", 1 * mm, (3, 3), 5, 3, WAVELENGTH,
    lenslet_aperture=40 * um,
)  # fmt: skip
RADII = torch.linspace(0.0, 12 * um, 97, dtype=F64)


def _masked(terms: dict[int, float]) -> ConventionalLFMSystem:
    return dataclasses.replace(SYSTEM, pupil_zernike_waves=tuple(terms.items()))


def _patterns(system: ConventionalLFMSystem, **kwargs) -> torch.Tensor:
    reach = max(system.support(abs(z)) for z in DEPTHS)
    return conventional_patterns(system, DEPTHS, reach=reach, dtype=F64, **kwargs)


def _relative(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm())


def test_zero_terms_and_no_terms_are_bit_identical():
    objective = SYSTEM.objective
    plain = debye_integral(objective, WAVELENGTH, RADII, torch.tensor(DEPTHS, dtype=F64))
    for empty in (None, {}):
        again = debye_integral(
            objective, WAVELENGTH, RADII, torch.tensor(DEPTHS, dtype=F64), zernike_waves=empty
        )
        assert torch.equal(again, plain)
    zero = debye_integral(
        objective, WAVELENGTH, RADII, torch.tensor(DEPTHS, dtype=F64), zernike_waves={1: 0.0, 4: 0.0, 11: 0.0}
    )
    assert torch.equal(zero, plain)
    assert torch.equal(_patterns(_masked({4: 0.0, 11: 0.0})), _patterns(SYSTEM))


@pytest.mark.parametrize("c", [0.05, -0.12])
def test_defocus_term_equals_the_closed_form_depth_shift_paraxial_model(c):
    """In the paraxial model the depth phase is -n k z sin^2(theta) / 2 = -pi z NA^2 rho^2 / (n lambda)
    (rho = sin(theta) n / NA); Noll 4 of c waves is 2 pi c sqrt(3) (2 rho^2 - 1). Equal rho^2 parts:
    mask c at depth z = no mask at z + dz, dz = -4 sqrt(3) c n lambda / NA^2, times the piston
    exp(-2 pi j sqrt(3) c). Exact up to rounding (same quadrature nodes)."""
    n_imm, na = 1.33, 0.8
    objective = ObjectiveLens(40.0, na, n_imm, 200 * mm)
    dz = -4 * math.sqrt(3) * c * n_imm * WAVELENGTH / na**2
    z = torch.tensor((-3 * um, 0.0, 2 * um), dtype=F64)
    kw = {"model": "paraxial", "n_quadrature": 400}
    masked = debye_integral(objective, WAVELENGTH, RADII, z, zernike_waves={4: c}, **kw)
    shifted = debye_integral(objective, WAVELENGTH, RADII, z + dz, **kw)
    piston = complex(math.cos(2 * math.pi * math.sqrt(3) * c), -math.sin(2 * math.pi * math.sqrt(3) * c))
    assert _relative(masked, shifted * piston) < 1e-10
    assert _relative(masked, debye_integral(objective, WAVELENGTH, RADII, z, **kw)) > 0.1  # it does defocus


def test_defocus_term_equals_the_paraxial_depth_shift_of_the_debye_field_at_low_na():
    """Debye model: the depth phase n k z (cos(theta) - 1) is quadratic in rho only paraxially; the
    residual after the shift is ~ n k dz sin^4(theta) / 8 <= 1.5e-3 rad at NA 0.1 in water (c = 0.05,
    dz = -24.2 um), so the intensities agree to ~1e-3 while the unshifted one differs by tens of %."""
    n_imm, na, c = 1.33, 0.1, 0.05
    objective = ObjectiveLens(4.0, na, n_imm, 200 * mm)
    dz = -4 * math.sqrt(3) * c * n_imm * WAVELENGTH / na**2
    assert dz == pytest.approx(-24.19 * um, rel=1e-3)
    radii = torch.linspace(0.0, 8 * um, 81, dtype=F64)
    z = torch.tensor((-5 * um, 4 * um), dtype=F64)
    masked = debye_integral(objective, WAVELENGTH, radii, z, zernike_waves={4: c}).abs() ** 2
    shifted = debye_integral(objective, WAVELENGTH, radii, z + dz).abs() ** 2
    plain = debye_integral(objective, WAVELENGTH, radii, z).abs() ** 2
    assert _relative(masked, shifted) < 3e-3
    assert _relative(masked, plain) > 0.1


def test_a_spherical_term_reaches_the_patterns_and_widens_the_lenslet_reach():
    """Noll 11 of 0.3 waves: transverse ray aberration up to 12 sqrt(5) 0.3 = 8.05 lambda / NA_img on
    the NIP, added to the geometric blur that plans the lenslet reach and light radius. Without it
    the plan kept the reach of the unmasked system and 10 % of the light fell outside the simulated
    lenslets; with it, two more lenslets of reach change the total by < 0.5 % (as for no mask:
    0.6 %). (Full fill factor here, so that no light is lost between clear apertures.)"""
    system = dataclasses.replace(_masked({11: 0.3}), lenslet_aperture=None)
    full = dataclasses.replace(SYSTEM, lenslet_aperture=None)
    na_img = 0.3 / 10.0
    assert system.blur_radius(6 * um) - full.blur_radius(6 * um) == pytest.approx(
        12 * math.sqrt(5) * 0.3 * WAVELENGTH / na_img, rel=1e-9
    )
    assert full.blur_radius(6 * um) == SYSTEM.blur_radius(6 * um)
    reach = max(system.support(abs(z)) for z in DEPTHS)
    assert reach > max(full.support(abs(z)) for z in DEPTHS)
    planned = conventional_patterns(system, DEPTHS, reach=reach, dtype=F64)
    wider = conventional_patterns(system, DEPTHS, reach=reach + 2, dtype=F64)
    assert float(planned.sum()) == pytest.approx(float(wider.sum()), rel=5e-3)
    plain = _patterns(full)
    pad = (planned.shape[-1] - plain.shape[-1]) // 2
    assert _relative(planned, torch.nn.functional.pad(plain, (pad, pad, pad, pad))) > 0.05


@pytest.mark.parametrize(("j", "n", "m"), [(2, 1, 1), (5, 2, 2), (7, 3, 1), (12, 4, 2)])
def test_terms_that_are_not_rotationally_symmetric_are_refused_by_name(j, n, m):
    match = rf"Noll {j} \(radial order n = {n}, azimuthal frequency m = {m}\) is not rotationally symmetric"
    with pytest.raises(ValueError, match=match):
        debye_integral(SYSTEM.objective, WAVELENGTH, RADII, 0.0, zernike_waves={4: 0.1, j: 0.1})
    with pytest.raises(ValueError, match="pupil_zernike_waves: " + match):
        _masked({j: 0.1})
    with pytest.raises(ValueError, match="lists a Noll index twice"):
        dataclasses.replace(SYSTEM, pupil_zernike_waves=((4, 0.1), (4, 0.2)))


def test_the_mask_is_part_of_the_system_identity():
    a, b, same = _masked({11: 0.2}), _masked({11: 0.3}), _masked({11: 0.2})
    assert a != SYSTEM and a != b and a == same and hash(a) == hash(same)
    assert _masked({11: 0.2, 4: 0.1}).pupil_zernike_waves == ((4, 0.1), (11, 0.2))  # sorted


def test_debye_gradcheck_in_the_coefficients():
    objective = ObjectiveLens(10.0, 0.3, 1.0, 200 * mm)
    z = torch.tensor((0.0, 5 * um), dtype=F64)
    weights = torch.rand(2, RADII.numel(), generator=torch.Generator().manual_seed(3), dtype=F64)

    def loss(c4, c11):
        field = debye_integral(objective, WAVELENGTH, RADII, z, zernike_waves={4: c4, 11: c11})
        return (weights * field.abs() ** 2).sum() * 1e-9

    inputs = (
        torch.tensor(0.07, dtype=F64, requires_grad=True),
        torch.tensor(-0.2, dtype=F64, requires_grad=True),
    )
    assert torch.autograd.gradcheck(loss, inputs, eps=1e-6, atol=1e-8, rtol=1e-5)


def test_pattern_gradient_equals_a_central_difference_of_the_float_path():
    """d loss / d c11 through the patterns (tensor override) against (L(c + h) - L(c - h)) / 2h of
    the plain float path with the system holding c +- h; at c the override reproduces the float path."""
    c0, h = -0.2, 1e-4
    system = _masked({4: 0.05, 11: c0})
    weights = torch.rand(_patterns(system).shape, generator=torch.Generator().manual_seed(7), dtype=F64)

    c = torch.tensor(c0, dtype=F64, requires_grad=True)
    patterns = _patterns(system, zernike_waves={11: c})
    assert _relative(patterns.detach(), _patterns(system)) < 1e-12
    loss = (weights * patterns).sum() * 1e2
    loss.backward()
    with torch.no_grad():
        up = (weights * _patterns(_masked({4: 0.05, 11: c0 + h}))).sum() * 1e2
        down = (weights * _patterns(_masked({4: 0.05, 11: c0 - h}))).sum() * 1e2
    numeric = float((up - down) / (2 * h))
    assert abs(numeric) > 1e-4
    assert float(c.grad) == pytest.approx(numeric, rel=1e-5)


def test_masked_debye_field_equals_the_tube_lens_transform_of_the_masked_pupil_field(monkeypatch):
    """High NA (40x/1.0 water): the Fourier path's pupil field with the same m = 0 mask, written on
    the pupil plane as Z_j(rho_xy / (NA f_obj)) (:func:`pupil_field`), turned into the image by the
    tube lens (a direct DFT sum), equals the masked image-side Debye field, whose mask is written
    at sin(theta) / sin(alpha): the two pupil coordinates agree through the sine condition
    rho = n f sin(theta). Tolerance as for the unmasked identity (pixelated rim; measured 6.4e-4 of
    the peak); the mask written at theta / alpha instead is off by 0.31 of the peak, a
    sign-flipped spherical term by 1.3."""
    obj = ObjectiveLens(40, 1.0, 1.33, 200 * mm)
    n_px = 256
    grid = Grid(n_px, 2.1 * obj.pupil_radius / n_px)
    waves = {4: 0.1, 11: -0.3, 22: 0.15}
    z = torch.tensor([0.0, 1.5 * um], dtype=F64)
    pupil = pupil_field(obj, grid, WAVELENGTH, z, zernike_waves=waves, dtype=torch.complex128).data
    f_t, m = 200 * mm, 40
    xi = torch.tensor([-8.0, -5.0, 0.0, 0.7, 3.0, 6.0, 10.0], dtype=F64) * um
    yi = torch.tensor([4.0, 0.0, 0.0, 0.3, -2.0, 5.0, 1.0], dtype=F64) * um
    ys, xs = grid.axes()
    kernel = torch.exp(
        -2j
        * math.pi
        * (xs[None, None, :] * xi[:, None, None] + ys[None, :, None] * yi[:, None, None])
        / (WAVELENGTH * f_t)
    )  # (P, ny, nx)
    image = (pupil[:, None] * kernel[None]).sum((-2, -1)) * (grid.pixel_area / (1j * WAVELENGTH * f_t))
    r = torch.sqrt((xi / m) ** 2 + (yi / m) ** 2)
    debye = debye_integral(obj, WAVELENGTH, r, z, zernike_waves=waves) / m
    peak = float(debye.abs().max())
    assert float((image - debye).abs().max()) < 5e-3 * peak
    wrong = debye_integral(obj, WAVELENGTH, r, z, zernike_waves={4: 0.1, 11: 0.3, 22: 0.15}) / m
    assert float((image - wrong).abs().max()) > 0.5 * peak
    original, alpha = debye_module.radial_zernike_phase, math.asin(1.0 / 1.33)
    monkeypatch.setattr(  # the mask at theta / alpha: the pupil coordinate a non-aplanatic mapping gives
        debye_module,
        "radial_zernike_phase",
        lambda w, rho: original(w, torch.asin(rho * math.sin(alpha)) / alpha),
    )
    wrong = debye_integral(obj, WAVELENGTH, r, z, zernike_waves=waves) / m
    assert float((image - wrong).abs().max()) > 0.1 * peak


def test_debye_psf_passes_the_mask_to_both_radial_samplings():
    objective = SYSTEM.objective
    grid = Grid(33, 0.3 * um)
    kw = {"zernike_waves": {11: 0.25}, "dtype": torch.complex128}
    exact = debye_psf(objective, grid, WAVELENGTH, 3 * um, radial_sampling="exact", **kw).data
    table = debye_psf(objective, grid, WAVELENGTH, 3 * um, radial_sampling=16, **kw).data
    plain = debye_psf(
        objective, grid, WAVELENGTH, 3 * um, radial_sampling="exact", dtype=torch.complex128
    ).data
    assert _relative(table, exact) < 1e-6
    assert _relative(exact, plain) > 0.05
