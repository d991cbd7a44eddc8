"""Sampling criteria, and every SamplingWarning / SamplingError: each names its criterion and a
grid (or distance) that satisfies it, and that suggestion is checked to actually satisfy it."""

from __future__ import annotations

import math
import re
import warnings

import pytest
import torch

from lfm_studio.engine.errors import SamplingError, SamplingWarning
from lfm_studio.engine.optics import sampling
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.propagation import propagate
from lfm_studio.engine.optics.sources import gaussian_beam
from lfm_studio.engine.units import mm, nm, um

C128 = torch.complex128
GRID_IN_MESSAGE = re.compile(r"Grid\(shape=\((\d+), (\d+)\), spacing=\(([\d.e+-]+) um, ([\d.e+-]+) um\)\)")


def _suggested_grid(message: str, index: int = -1) -> Grid:
    """The ``index``-th grid named in a message (default: the last, i.e. the suggestion)."""
    ny, nx, dy, dx = GRID_IN_MESSAGE.findall(message)[index]
    return Grid((int(ny), int(nx)), (float(dy) * um, float(dx) * um))


def _no_sampling_warning(function, *args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("error", SamplingWarning)
        return function(*args, **kwargs)


# -- criteria ------------------------------------------------------------------------------------
def test_fresnel_number_and_critical_distance():
    assert sampling.fresnel_number(100 * um, 500 * nm, 20 * mm) == pytest.approx(1.0)
    grid = Grid((100, 200), (2 * um, 1 * um))
    assert sampling.critical_distance(grid, 500 * nm) == pytest.approx(200 * (1 * um) ** 2 / (500 * nm))


def test_bandlimit_frequency_is_matsushima_shimobaba_of_the_padded_window():
    grid = Grid((256, 512), 1 * um)  # padded window 256 x 512 um
    z, wavelength = 3 * mm, 500 * nm
    fy, fx = sampling.bandlimit_frequency(grid, wavelength, z)
    assert fy == pytest.approx(1.0 / (wavelength * math.sqrt((2 * z / (256 * um)) ** 2 + 1)), rel=1e-14)
    assert fx == pytest.approx(1.0 / (wavelength * math.sqrt((2 * z / (512 * um)) ** 2 + 1)), rel=1e-14)
    assert sampling.bandlimit_frequency(grid, wavelength, -z) == (fy, fx)  # depends on |z|
    assert sampling.bandlimit_frequency(grid, wavelength, 0.0) == pytest.approx((2e6, 2e6))  # 1/lambda
    # The padded shape it suggests reaches a requested bandwidth (and Nyquist caps it).
    need = sampling.padded_shape_for_bandwidth(grid, wavelength, z, (1e5, 3e5))
    assert all(
        f >= t
        for f, t in zip(
            sampling.bandlimit_frequency(grid.with_shape(need), wavelength, z), (1e5, 3e5), strict=True
        )
    )
    assert sampling.padded_shape_for_bandwidth(grid, 2 * um, z, (1e5, 5e5)) is None  # 5e5 = 1/lambda


def test_fresnel_phase_error_is_thesis_eq_3_13_for_small_angles_and_infinite_past_the_cutoff():
    wavelength, z = 500 * nm, 10 * mm
    theta = 1e-3
    small = sampling.fresnel_phase_error(theta / wavelength, wavelength, z)
    assert small == pytest.approx(math.pi * theta**4 * z / (4 * wavelength), rel=1e-6)
    large = sampling.fresnel_phase_error(0.5 / wavelength, wavelength, z)  # 30 degrees
    exact = 2 * math.pi * z / wavelength * ((1 - 0.125) - math.sqrt(1 - 0.25))
    assert large == pytest.approx(exact, rel=1e-9)
    assert sampling.fresnel_phase_error(1.0 / wavelength, wavelength, z) == math.inf
    f = sampling.max_fresnel_frequency(wavelength, z, limit=0.3)
    assert sampling.fresnel_phase_error(f, wavelength, z) == pytest.approx(0.3, rel=1e-9)


# -- warnings ------------------------------------------------------------------------------------
def test_quadratic_phase_undersampling_warns_and_names_a_grid_that_samples_it():
    grid = Grid(512, 2 * um)
    wavelength, focal_length = 500 * nm, 1 * mm
    assert sampling.check_quadratic_phase_sampling(grid, wavelength, focal_length, 100 * um)  # limit 125 um
    with pytest.warns(
        SamplingWarning, match=r"quadratic phase \(lens/MLA\) undersampled: r_max = 200 um"
    ) as record:
        assert not sampling.check_quadratic_phase_sampling(grid, wavelength, focal_length, 200 * um)
    assert record[0].filename == __file__  # attributed to the caller, not to the engine
    better = _suggested_grid(str(record[0].message))
    assert better.dx == pytest.approx(1.25 * um, rel=1e-3)  # lambda f / (2 r)
    assert better.extent[1] >= grid.extent[1]  # same field of view
    assert _no_sampling_warning(
        sampling.check_quadratic_phase_sampling, better, wavelength, focal_length, 200 * um
    )
    # A 0-d tensor focal length (trainable) and a diverging lens are accepted.
    assert sampling.check_quadratic_phase_sampling(grid, wavelength, torch.tensor(-1e-3), 100 * um)


def test_energy_at_the_window_edge_warns_and_names_a_larger_grid():
    wavelength = 500 * nm
    grid = Grid(64, 2 * um)
    wide = gaussian_beam(grid, wavelength, 40 * um, dtype=C128)
    with pytest.warns(
        SamplingWarning, match=r"energy at the window edge: 0\.\d+ of the field's power"
    ) as record:
        propagate(wide, 100 * um)
    assert record[0].filename == __file__
    better = _suggested_grid(str(record[0].message))
    assert better.shape == (128, 128) and better.spacing == grid.spacing
    _no_sampling_warning(propagate, gaussian_beam(better, wavelength, 40 * um, dtype=C128), 100 * um)


def test_fresnel_phase_error_at_nyquist_warns_and_names_a_coarser_grid():
    wavelength = 500 * nm
    grid = Grid(128, 1 * um)
    beam = gaussian_beam(grid, wavelength, 15 * um, dtype=C128)
    z = 500 * um  # phase error at Nyquist (5e5 / m): pi z l^3 f^4 / 4 = 3.1 rad
    with pytest.warns(SamplingWarning, match=r"Fresnel approximation \(thesis eq. 3.13") as record:
        propagate(beam, z, method="fresnel_tf")
    better = _suggested_grid(str(record[0].message))
    assert better.dx > grid.dx and better.extent[1] <= grid.extent[1] * (1 + 1e-9)
    assert _no_sampling_warning(sampling.check_fresnel_approximation, better, wavelength, z)
    # The impulse-response form checks the same criterion.
    with pytest.warns(SamplingWarning, match="Fresnel approximation"):
        propagate(beam, 3 * mm, method="fresnel_ir")


def _rough_field(grid: Grid, wavelength: float) -> Field:
    """A small square aperture: content up to Nyquist, well inside the window."""
    y, x = grid.axes()
    inside = (x.abs() < 8 * grid.dx)[None, :] & (y.abs() < 8 * grid.dy)[:, None]
    return Field(inside.to(C128), grid, wavelength)


@pytest.mark.parametrize(
    ("method", "criterion"),
    [
        ("bandlimited_asm", r"band limit \(Matsushima-Shimobaba 2009\) below Nyquist: it removes"),
        ("asm", r"asm transfer function undersampled beyond the band limit \(z > critical distance"),
    ],
)
def test_band_limit_below_nyquist_warns_when_it_removes_power_and_names_the_padding(method, criterion):
    wavelength = 500 * nm
    grid = Grid(64, 1 * um)
    field = _rough_field(grid, wavelength)
    z = 300 * um  # padded critical distance 128 um^2 / 0.5 um = 256 um
    with pytest.warns(SamplingWarning, match=criterion) as record:
        propagate(field, z, method=method)
    message = str(record[0].message)
    need = _suggested_grid(message)
    assert need.spacing == grid.spacing and need.nx > 128
    _no_sampling_warning(propagate, field, z, method=method, padding=need.nx / grid.nx)
    # A smooth beam on the same grid and distance: band limit below Nyquist but no power there.
    _no_sampling_warning(propagate, gaussian_beam(grid, wavelength, 8 * um, dtype=C128), z, method=method)


def test_fresnel_transfer_function_aliasing_warns_beyond_the_critical_distance():
    wavelength = 500 * nm
    grid = Grid(64, 4 * um)  # coarse: Fresnel phase error at Nyquist stays small (0.4 rad)
    y, x = grid.axes()
    field = Field(((x.abs() < 4 * um)[None, :] & (y.abs() < 4 * um)[:, None]).to(C128), grid, wavelength)
    z = 10 * mm  # padded critical distance 128 * 16 um^2 / 0.5 um = 4.1 mm
    with pytest.warns(SamplingWarning, match=r"fresnel_tf transfer function undersampled"):
        propagate(field, z, method="fresnel_tf")


# -- errors --------------------------------------------------------------------------------------
def test_far_field_of_the_padded_window_is_a_sampling_error_naming_the_grid():
    wavelength = 500 * nm
    grid = Grid(32, 1 * um)
    field = gaussian_beam(grid, wavelength, 3 * um, dtype=C128)
    z = 10 * mm  # (32 um)^2 / (lambda z) = 0.2: far field of the 64 um padded window
    criterion = r"far field of the padded window .*\(Fresnel number a\^2 / \(lambda z\) = 0.205 < 1\)"
    with pytest.raises(SamplingError, match=criterion) as info:
        propagate(field, z, method="bandlimited_asm")
    need = _suggested_grid(str(info.value))
    assert sampling.fresnel_number(need.extent[1] / 2, wavelength, z) >= 1.0
    assert "method='fresnel_ir'" in str(info.value)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SamplingWarning)  # the band limit still cuts; not an error
        propagate(field, z, method="bandlimited_asm", padding=need.nx / grid.nx)
    with pytest.warns(SamplingWarning, match="Fresnel approximation"):  # Nyquist at 14.5 deg: physics
        out = propagate(field, z, method="fresnel_ir")  # the suggested method has no SamplingError
    assert out.grid.dx == pytest.approx(wavelength * z / (64 * 1 * um))


def test_fresnel_ir_output_window_smaller_than_the_field_is_a_sampling_error():
    wavelength = 500 * nm
    grid = Grid(128, 2 * um)
    field = gaussian_beam(grid, wavelength, 30 * um, dtype=C128)
    with pytest.raises(
        SamplingError, match=r"fresnel_ir.*cannot hold the field.*needs z >= ([\d.]+) mm"
    ) as info:
        propagate(field, 100 * um, method="fresnel_ir")
    z_min = float(re.search(r"needs z >= ([\d.e+-]+) mm", str(info.value)).group(1)) * mm
    assert 100 * um < z_min < 1 * mm
    out = _no_sampling_warning(propagate, field, 1.02 * z_min, method="fresnel_ir")
    assert out.grid.dx == pytest.approx(wavelength * 1.02 * z_min / (256 * 2 * um), rel=1e-3)


def test_padded_grid_above_the_sane_limit_is_refused_before_allocating():
    field = Field(torch.zeros((1, 4096, 4096), dtype=torch.complex64), Grid(4096, 1 * um), 500 * nm)
    with pytest.raises(SamplingError, match=r"padded grid 20480 x 20480 exceeds the limit of \d+ samples"):
        propagate(field, 1 * mm, padding=5.0)
