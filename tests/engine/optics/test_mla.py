"""Microlens arrays: layout validation, generators, Algorithm-1 transmission, focusing, gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.special import j1

from lfm_studio.engine.errors import SamplingWarning
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.lenses import thin_lens
from lfm_studio.engine.optics.mla import apply_mla, mla_transmission
from lfm_studio.engine.optics.mla_generators import hex_grid, square_grid
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.pupils import square_pupil
from lfm_studio.engine.optics.sources import plane_wave
from lfm_studio.engine.units import mm, nm, um

WAVELENGTH = 500 * nm


# -- transmission ------------------------------------------------------------------------
@pytest.mark.parametrize("antialias", [False, True], ids=["binary", "antialiased"])
@pytest.mark.parametrize("center_um", [(0.0, 0.0), (3.0, -2.0), (3.37, -2.71), (-5.5, 4.5)])
def test_single_lenslet_equals_thin_lens_with_pupil(center_um, antialias):
    # Two independent code paths: full-grid thin_lens + circular pupil vs the patch
    # placed at the nearest pixel and evaluated around the true (sub-pixel) centre.
    # Both form the same float64 expressions: agreement to rounding (1e-12).
    grid = Grid(64, 1 * um)
    field = plane_wave(grid, WAVELENGTH, refractive_index=1.33, dtype=torch.complex128)
    center = (center_um[0] * um, center_um[1] * um)
    mla = MicrolensArray((Lenslet(center, 21 * um, 300 * um),))
    out = apply_mla(field, mla, antialias=antialias)
    expected = thin_lens(field, 300 * um, aperture_diameter=21 * um, center=center, antialias=antialias)
    torch.testing.assert_close(out.data, expected.data, rtol=0, atol=1e-12)


def test_square_lenslet_equals_thin_lens_with_square_pupil():
    grid = Grid(64, 1 * um)
    field = plane_wave(grid, WAVELENGTH, dtype=torch.complex128)
    center = (4.26 * um, -7.51 * um)
    mla = MicrolensArray((Lenslet(center, 17.3 * um, 300 * um, "square"),))
    out = apply_mla(field, mla, antialias=True)
    expected = thin_lens(field, 300 * um, center=center).data * square_pupil(
        grid, 17.3 * um, center=center, antialias=True
    )
    torch.testing.assert_close(out.data, expected, rtol=0, atol=1e-12)


MIXED = MicrolensArray(
    (
        Lenslet((0.3 * um, -0.2 * um), 20 * um, 400 * um),
        Lenslet((25.7 * um, 3.1 * um), 16 * um, 300 * um, "square"),
        Lenslet((-21.45 * um, 10.5 * um), 18 * um, 500 * um),
        Lenslet((10.3 * um, -20.2 * um), 12 * um, 400 * um),
        Lenslet((-9.7 * um, -20.2 * um), 12 * um, 400 * um),  # same patch as the one above
        Lenslet((-30.0 * um, -30.0 * um), 14 * um, 450 * um),  # partly outside the grid: cropped
    )
)


def _numpy_reference(mla: MicrolensArray, grid: Grid, k: float) -> np.ndarray:
    """O(lenslets x grid) brute force of eq. 3.15 per lenslet with a binary pupil."""
    y, x = (a.numpy() for a in grid.axes())
    out = np.zeros(grid.shape, dtype=complex)
    for lens in mla:
        xr, yr = x[None, :] - lens.center[0], y[:, None] - lens.center[1]
        if lens.shape == "circle":
            inside = xr**2 + yr**2 <= lens.half_width**2
        else:
            inside = (np.abs(xr) <= lens.half_width) & (np.abs(yr) <= lens.half_width)
        out += inside * np.exp(-1j * k * (xr**2 + yr**2) / (2 * float(lens.focal_length)))
    return out


def test_mixed_layout_matches_brute_force_and_gradient_path():
    grid = Grid(64, 1 * um)
    reference = _numpy_reference(MIXED, grid, 2 * math.pi / WAVELENGTH)
    fast = mla_transmission(MIXED, grid, WAVELENGTH, dtype=torch.complex128)
    assert fast.shape == (64, 64) and fast.dtype == torch.complex128
    assert np.abs(fast.numpy() - reference).max() < 1e-12
    # per-lenslet evaluation (gradient path) gives the same mask as the shared patches
    focal = MIXED.focal_lengths().requires_grad_()
    per_lenslet = mla_transmission(MIXED, grid, WAVELENGTH, focal_lengths=focal, dtype=torch.complex128)
    torch.testing.assert_close(per_lenslet.detach(), fast, rtol=0, atol=1e-12)
    # complex64 result, same geometry
    single = mla_transmission(MIXED, grid, WAVELENGTH)
    assert single.dtype == torch.complex64 and np.abs(single.numpy() - reference).max() < 1e-6


# 3 x 3 focusing set-up: pitch 64 um, D = 60 um, f = 500 um, shifted by a sub-pixel offset;
# N dx^2 / lambda = 512 um >= f, so an ASM kernel over f is sampled on the window.
FOCUS_N, FOCUS_DX, FOCUS_F, FOCUS_PITCH, FOCUS_D = 256, 1 * um, 500 * um, 64 * um, 60 * um


def _mla_field_3x3() -> tuple[MicrolensArray, Field]:
    grid = Grid(FOCUS_N, FOCUS_DX)
    mla = square_grid(
        FOCUS_PITCH, FOCUS_F, count=3, aperture_fraction=FOCUS_D / FOCUS_PITCH, offset=(0.3 * um, -0.4 * um)
    )
    return mla, apply_mla(plane_wave(grid, WAVELENGTH, dtype=torch.complex128), mla, antialias=True)


def _check_foci(intensity: np.ndarray, mla: MicrolensArray, grid: Grid) -> None:
    n, dx = FOCUS_N, FOCUS_DX
    y, x = (a.numpy() for a in grid.axes())
    # Paraxial focal-point intensity of a unit plane wave through a circular lens:
    # (pi a^2 / (lambda f))^2 = 128. Budget: non-paraxial ASM (NA 0.06), antialiased pupil
    # area (~1e-5), light from the neighbours' apertures: measured within 0.4%; tolerance 1%.
    peak = (math.pi * (FOCUS_D / 2) ** 2 / (WAVELENGTH * FOCUS_F)) ** 2
    for lens in mla:
        cx, cy = lens.center
        i, j = round(cy / dx) + n // 2, round(cx / dx) + n // 2
        window = intensity[i - 5 : i + 6, j - 5 : j + 6]  # Airy first zero at 5.1 um
        assert window.max() == pytest.approx(intensity.max(), rel=0.02)  # all foci alike (measured 0.5%)
        # the pixel sits 0.5 um from the focus: Airy factor [2 J1(v) / v]^2 = 0.964 there
        v = 2 * math.pi * (FOCUS_D / 2) * math.hypot(x[j] - cx, y[i] - cy) / (WAVELENGTH * FOCUS_F)
        assert intensity[i, j] == pytest.approx(peak * (2 * j1(v) / v) ** 2, rel=0.01)
        # Centroid inside the first dark ring follows the sub-pixel centre (placing patches at
        # the nearest pixel without the offset would miss by 0.3-0.4 um). Budget: the window
        # truncation and the neighbours' light bias it by up to 0.013 um (measured).
        wy, wx = np.meshgrid(y[i - 5 : i + 6], x[j - 5 : j + 6], indexing="ij")
        mask = (wx - x[j]) ** 2 + (wy - y[i]) ** 2 <= (5 * dx) ** 2
        total = (window * mask).sum()
        assert (window * mask * wx).sum() / total == pytest.approx(cx, abs=0.03 * um)
        assert (window * mask * wy).sum() / total == pytest.approx(cy, abs=0.03 * um)
    # between the lenslets' foci there is (almost) no light
    assert intensity[n // 2, n // 2 + 32] < 0.01 * peak


def test_three_by_three_array_focuses_behind_each_lenslet():
    # Exact ASM over f as a test-local numpy reference (independent of the engine's propagator).
    mla, field = _mla_field_3x3()
    fy, fx = np.fft.fftfreq(FOCUS_N, FOCUS_DX)[:, None], np.fft.fftfreq(FOCUS_N, FOCUS_DX)[None, :]
    kernel = np.exp(2j * np.pi * FOCUS_F * np.sqrt(1 / WAVELENGTH**2 - fx**2 - fy**2))
    intensity = np.abs(np.fft.ifft2(np.fft.fft2(field.data.numpy()) * kernel)) ** 2
    _check_foci(intensity, mla, field.grid)


def test_three_by_three_array_focuses_with_the_engine_propagator():
    propagation = pytest.importorskip("lfm_studio.engine.optics.propagation")
    mla, field = _mla_field_3x3()
    focused = propagation.propagate(field, FOCUS_F, method="bandlimited_asm")
    _check_foci(focused.intensity().numpy(), mla, field.grid)


def test_undersampled_lenslet_warns():
    grid = Grid(64, 1 * um)
    mla = MicrolensArray((Lenslet((0.0, 0.0), 40 * um, 60 * um),))  # 20 um > lambda f / (2 dx) = 15 um
    with pytest.warns(SamplingWarning, match="undersampled"):
        mla_transmission(mla, grid, WAVELENGTH)
    mla_transmission(
        MicrolensArray((Lenslet((0.0, 0.0), 40 * um, 80 * um),)), grid, WAVELENGTH
    )  # at the limit


# -- generators ----------------------------------------------------------------------------
def _centres_um(mla: MicrolensArray) -> np.ndarray:
    return mla.centers().numpy() / um


def _nearest_distances(centres: np.ndarray) -> np.ndarray:
    d = np.linalg.norm(centres[:, None, :] - centres[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    return d


def test_square_grid_count_pitch_and_centres():
    mla = square_grid(100 * um, 2 * mm, count=3)
    assert len(mla) == 9 and all(lens.aperture_diameter == pytest.approx(100 * um) for lens in mla)
    expected = np.array([(x, y) for y in (-100, 0, 100) for x in (-100, 0, 100)], dtype=float)
    np.testing.assert_allclose(_centres_um(mla), expected, atol=1e-9)  # row by row, increasing y
    np.testing.assert_allclose(_nearest_distances(_centres_um(mla)).min(axis=1), 100.0, rtol=1e-12)
    rect = square_grid(100 * um, 2 * mm, count=(2, 4), aperture_fraction=0.5, shape="square")
    assert (
        len(rect) == 8 and rect[0].shape == "square" and rect[0].aperture_diameter == pytest.approx(50 * um)
    )
    assert sorted(set(np.round(_centres_um(rect)[:, 0], 9))) == [-150, -50, 50, 150]
    assert sorted(set(np.round(_centres_um(rect)[:, 1], 9))) == [-50, 50]


def test_square_grid_region_filters():
    # extent 350 x 250 um, D = 80 um: |m| * 100 + 40 <= 175 (x) and <= 125 (y) -> 3 x 1
    boxed = square_grid(100 * um, 2 * mm, extent=(350 * um, 250 * um), aperture_fraction=0.8)
    assert len(boxed) == 3 and boxed.extent == (350 * um, 250 * um)
    # circular array aperture of 500 um, D = 100 um: sites with 100 sqrt(i^2 + j^2) <= 200 -> 13
    round_array = square_grid(100 * um, 2 * mm, aperture_diameter=500 * um)
    assert len(round_array) == 13 and round_array.aperture_diameter == pytest.approx(500 * um)
    assert float(np.linalg.norm(_centres_um(round_array), axis=1).max()) == pytest.approx(200.0)


def test_hex_grid_rings_neighbours_and_region():
    pitch = 50 * um
    mla = hex_grid(pitch, 1 * mm, rings=2)
    assert len(mla) == 1 + 3 * 2 * 3
    c = _centres_um(mla)
    d = _nearest_distances(c)
    np.testing.assert_allclose(d.min(axis=1), 50.0, rtol=1e-12)  # touching circles (fraction 1)
    centre = int(np.argmin(np.linalg.norm(c, axis=1)))
    assert np.isclose(d[centre], 50.0, rtol=1e-12).sum() == 6
    rows = np.unique(np.round(c[:, 1], 9))
    np.testing.assert_allclose(np.diff(rows), 50.0 * math.sqrt(3) / 2, rtol=1e-9)  # rounded to 1e-9 um
    # An aperture that just holds the first ring (neighbours touch the rim) keeps 7.
    ring1 = hex_grid(pitch, 1 * mm, aperture_diameter=2 * (pitch + pitch / 2))
    assert len(ring1) == 7
    with pytest.raises(
        ValueError, match=r"lenslet 0 \(square.* and lenslet 2 \(square.*overlap by 1\.69873 um"
    ):
        hex_grid(
            pitch, 1 * mm, rings=1, shape="square", aperture_fraction=0.9
        )  # 45 um > row spacing 43.30 um
    assert len(hex_grid(pitch, 1 * mm, rings=1, shape="square", aperture_fraction=0.85)) == 7


# -- validation ----------------------------------------------------------------------------
def test_overlapping_lenslets_are_rejected_with_names_and_overlap():
    a = Lenslet((0.0, 0.0), 150 * um, 3 * mm)
    b = Lenslet((100 * um, 0.0), 150 * um, 3 * mm)
    with pytest.raises(
        ValueError,
        match=r"lenslet 0 \(circle, centre \(0, 0\) um, diameter 150 um\) and "
        r"lenslet 1 \(circle, centre \(100, 0\) um, diameter 150 um\) overlap by 50 um",
    ):
        MicrolensArray((a, b))
    far = Lenslet((0.0, 500 * um), 150 * um, 3 * mm)
    sq = Lenslet((600 * um, 500 * um), 60 * um, 3 * mm, "square")
    touching = Lenslet((150 * um, 0.0), 150 * um, 3 * mm)
    MicrolensArray((a, touching, far))  # apertures that touch are fine
    circle_into_square = Lenslet((680 * um, 500 * um), 120 * um, 3 * mm)  # reaches 620 um < 630 um
    with pytest.raises(
        ValueError, match=r"lenslet 3 \(square, .* side 60 um\) and lenslet 4 .* overlap by 10 um"
    ):
        MicrolensArray((a, touching, far, sq, circle_into_square))


def test_lenslets_outside_the_array_are_rejected():
    inside = Lenslet((0.0, 0.0), 50 * um, 1 * mm)
    outside = Lenslet((100 * um, 0.0), 50 * um, 1 * mm)
    with pytest.raises(
        ValueError,
        match=r"lenslet 1 \(circle, centre \(100, 0\) um, diameter 50 um\) lies outside the array: its edge "
        r"reaches 125 um from the axis, beyond the array aperture radius 100 um",
    ):
        MicrolensArray((inside, outside), aperture_diameter=200 * um)
    with pytest.raises(ValueError, match=r"lenslet 1 .* extends beyond the array extent 200 x 400 um"):
        MicrolensArray((inside, outside), extent=(200 * um, 400 * um))
    MicrolensArray((inside, outside), extent=(250 * um, 50 * um))  # touching the edges is fine


def test_named_errors():
    with pytest.raises(ValueError, match="Lenslet focal_length must be a finite number > 0 m; got 0 m"):
        Lenslet((0.0, 0.0), 10 * um, 0.0)
    with pytest.raises(ValueError, match="Lenslet focal_length must be a finite number > 0 m; got nan"):
        Lenslet((0.0, 0.0), 10 * um, float("nan"))
    with pytest.raises(
        ValueError, match="Lenslet aperture_diameter must be a finite number > 0 m; got -1e-05 m"
    ):
        Lenslet((0.0, 0.0), -10 * um, 1 * mm)
    with pytest.raises(ValueError, match="Lenslet center x must be finite"):
        Lenslet((float("nan"), 0.0), 10 * um, 1 * mm)
    with pytest.raises(ValueError, match="Lenslet shape must be one of"):
        Lenslet((0.0, 0.0), 10 * um, 1 * mm, "hexagon")
    with pytest.raises(ValueError, match="at least one lenslet"):
        MicrolensArray(())
    with pytest.raises(ValueError, match="give either count or a region"):
        square_grid(100 * um, 1 * mm, count=3, extent=1 * mm)
    with pytest.raises(ValueError, match="give either rings or a region"):
        hex_grid(100 * um, 1 * mm)
    with pytest.raises(ValueError, match="pitch must be a finite number > 0 m"):
        square_grid(0.0, 1 * mm, count=2)
    grid = Grid(32, 1 * um)
    mla = square_grid(10 * um, 1 * mm, count=2)
    with pytest.raises(ValueError, match=r"focal_lengths must be a real tensor of shape \(4,\)"):
        mla_transmission(mla, grid, WAVELENGTH, focal_lengths=torch.ones(3))
    with pytest.raises(ValueError, match=r"focal length of lenslet 1 must be > 0 m; got -0\.001 m"):
        mla_transmission(mla, grid, WAVELENGTH, focal_lengths=torch.tensor([1e-3, -1e-3, 1e-3, 1e-3]))
    with pytest.raises(ValueError, match="focal_lengths contains 1 NaN/Inf"):
        mla_transmission(mla, grid, WAVELENGTH, focal_lengths=torch.tensor([1e-3, float("nan"), 1e-3, 1e-3]))


# -- gradients, devices ------------------------------------------------------------------------
def test_gradcheck_field_and_focal_lengths():
    grid = Grid(16, 1 * um)
    mla = square_grid(7 * um, 100 * um, count=2, aperture_fraction=6 / 7)  # half-width 3 um <= 25 um
    gen = torch.Generator().manual_seed(0)
    data = torch.randn((16, 16), dtype=torch.complex128, generator=gen, requires_grad=True)
    f_um = torch.tensor([100.0, 80.0, 120.0, 90.0], dtype=torch.float64, requires_grad=True)

    def run(data, f_um):
        return apply_mla(Field(data, grid, WAVELENGTH), mla, focal_lengths=f_um * um, antialias=True).data

    assert torch.autograd.gradcheck(run, (data, f_um), fast_mode=True)
    # A tensor focal length inside a Lenslet is differentiable too, and matches the override.
    f0 = torch.tensor(100 * um, dtype=torch.float64, requires_grad=True)
    lenses = (Lenslet((0.0, 0.0), 6 * um, f0), Lenslet((7 * um, 0.0), 6 * um, 100 * um))
    out = apply_mla(Field(data.detach(), grid, WAVELENGTH), MicrolensArray(lenses)).data
    (grad,) = torch.autograd.grad(out.abs().sum() + out.real.sum(), f0)
    assert float(grad) != 0.0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    grid = Grid(64, 1 * um)
    cpu = mla_transmission(MIXED, grid, WAVELENGTH, antialias=True)
    gpu = mla_transmission(MIXED, grid, WAVELENGTH, antialias=True, device="cuda")
    assert gpu.device.type == "cuda"
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=0, atol=1e-6)
