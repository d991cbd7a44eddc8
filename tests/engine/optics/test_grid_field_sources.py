"""Grid, Field and source constructors: conventions, closed forms and named errors."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.sources import gaussian_beam, plane_wave, point_source
from lfm_studio.engine.units import mm, nm, um


def test_grid_coordinates_are_centred_on_index_n_half():
    grid = Grid((4, 5), (1 * um, 2 * um))
    y, x = grid.axes()
    assert y.tolist() == pytest.approx([-2e-6, -1e-6, 0.0, 1e-6])
    assert x.tolist() == pytest.approx([-4e-6, -2e-6, 0.0, 2e-6, 4e-6])
    fy, fx = grid.frequency_axes()
    assert float(fy[2]) == 0.0 and float(fx[2]) == 0.0
    assert float(fx[3]) == pytest.approx(1.0 / (5 * 2e-6))


def test_fourier_dual_spacing_is_lambda_f_over_n_dx():
    grid = Grid(256, 5 * um)
    dual = grid.fourier_dual(500 * nm * 100 * mm)
    assert dual.dx == pytest.approx(500e-9 * 0.1 / (256 * 5e-6))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"shape": 0, "spacing": 1e-6}, "shape ny must be a positive integer; got 0"),
        ({"shape": 8, "spacing": -1e-6}, r"spacing dy must be a finite number > 0 m; got -1e-06 m"),
        ({"shape": 8, "spacing": float("nan")}, "spacing dy must be a finite number > 0 m; got nan"),
    ],
)
def test_grid_rejects_bad_input_naming_the_parameter(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Grid(**kwargs)


def test_field_rejects_bad_input_naming_the_problem():
    grid = Grid(8, 1 * um)
    good = torch.ones(8, 8, dtype=torch.complex64)
    with pytest.raises(ValueError, match=r"wavelength must be a finite number > 0 m; got -5e-07 m"):
        Field(good, grid, -500 * nm)
    with pytest.raises(ValueError, match=r"Field.data contains 1 NaN/Inf value\(s\) of 64"):
        bad = good.clone()
        bad[3, 3] = float("nan")
        Field(bad, grid, 500 * nm)
    with pytest.raises(TypeError, match="must be complex"):
        Field(torch.ones(8, 8), grid, 500 * nm)
    with pytest.raises(ValueError, match=r"shape \(8, 7\) does not end in the grid shape \(8, 8\)"):
        Field(torch.ones(8, 7, dtype=torch.complex64), grid, 500 * nm)


def test_field_compatibility_check_names_mismatch():
    a = plane_wave(Grid(8, 1 * um), 500 * nm)
    b = plane_wave(Grid(8, 2 * um), 500 * nm)
    c = plane_wave(Grid(8, 1 * um), 600 * nm)
    with pytest.raises(ValueError, match="mismatched grids"):
        a.require_compatible(b)
    with pytest.raises(ValueError, match="mismatched wavelengths"):
        a.require_compatible(c)


def test_plane_wave_tilt_has_the_expected_phase_gradient():
    grid = Grid(64, 1 * um)
    alpha = 0.1
    field = plane_wave(grid, 500 * nm, direction_cosines=(alpha, 0.0), dtype=torch.complex128)
    step = torch.angle(field.data[0, 1] / field.data[0, 0])
    assert float(step) == pytest.approx(2 * math.pi / 500e-9 * alpha * 1e-6, rel=1e-12)
    assert float(field.intensity().max()) == pytest.approx(1.0)


def test_point_source_paraxial_agrees_with_exact_near_the_axis():
    # Phase difference exact - paraxial = -k rho^4/(8 z^3) to leading order: at rho = 20 um,
    # z = 5 mm, lambda = 500 nm that is 2.0e-6 rad; we check against that expansion.
    grid = Grid(41, 1 * um)
    z = 5 * mm
    exact = point_source(grid, 500 * nm, z, dtype=torch.complex128)
    paraxial = point_source(grid, 500 * nm, z, paraxial=True, dtype=torch.complex128)
    rho2 = grid.radius_squared()
    k = 2 * math.pi / 500e-9
    dphi = torch.angle(exact.data / paraxial.data)
    expected = -k * rho2**2 / (8 * z**3)
    assert torch.allclose(dphi, expected, atol=1e-9)


def test_point_source_exact_matches_spherical_wave_far_off_axis():
    # High angle (rho ~ z): the stable form must equal k (sqrt(rho^2+z^2) - z) exactly.
    grid = Grid(33, 5 * um)
    z = 40 * um
    field = point_source(grid, 500 * nm, z, position=(10 * um, -5 * um), dtype=torch.complex128)
    y, x = grid.axes()
    r = torch.sqrt((x[None, :] - 10e-6) ** 2 + (y[:, None] + 5e-6) ** 2 + z**2)
    reference = torch.polar(1.0 / r, 2 * math.pi / 500e-9 * (r - z))
    assert torch.allclose(field.data, reference, rtol=1e-10, atol=0)


def test_converging_point_source_is_the_conjugate_of_diverging():
    grid = Grid(16, 1 * um)
    out = point_source(grid, 500 * nm, 1 * mm, dtype=torch.complex128)
    back = point_source(grid, 500 * nm, -1 * mm, dtype=torch.complex128)
    assert torch.allclose(back.data, out.data.conj())


def test_gaussian_beam_width_curvature_and_gouy_phase():
    wavelength, w0 = 500 * nm, 20 * um
    z_r = math.pi * w0**2 / wavelength
    grid = Grid(256, 1 * um)
    beam = gaussian_beam(grid, wavelength, w0, distance_from_waist=z_r, dtype=torch.complex128)
    # At z = z_R: w = sqrt(2) w0, R = 2 z_R, Gouy phase = pi/4, on-axis amplitude 1/sqrt(2).
    centre = beam.data[128, 128]
    assert float(centre.abs()) == pytest.approx(1 / math.sqrt(2), rel=1e-12)
    assert float(torch.angle(centre)) == pytest.approx(-math.pi / 4, rel=1e-12)
    row = beam.data[128]
    x = grid.axes()[1]
    w = math.sqrt(2) * w0
    i_edge = 128 + 28  # 28 um from the axis
    ratio = float(row[i_edge].abs() / centre.abs())
    assert ratio == pytest.approx(math.exp(-((28e-6 / w) ** 2)), rel=1e-12)
    curvature = float(torch.angle(row[i_edge] / centre))
    k = 2 * math.pi / wavelength
    assert curvature == pytest.approx((k * x[i_edge] ** 2 / (2 * 2 * z_r)).item(), rel=1e-9)


def test_sources_follow_device_and_dtype():
    field = plane_wave(Grid(8, 1 * um), 500 * nm, dtype=torch.complex128)
    assert field.dtype == torch.complex128
    single = field.to(dtype=torch.complex64)
    assert single.dtype == torch.complex64 and single.grid == field.grid


def test_power_is_intensity_times_area():
    grid = Grid(10, 2 * um)
    field = plane_wave(grid, 500 * nm, amplitude=3.0)
    assert float(field.power()) == pytest.approx(9.0 * 100 * 4e-12, rel=1e-6)
