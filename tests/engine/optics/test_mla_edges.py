"""MLA transmission at shared edges, on thin grids and in periodic windows (issue 22, items 1-3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.mla import mla_transmission
from lfm_studio.engine.optics.mla_generators import hex_grid, square_grid
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.units import nm, um

WAVELENGTH = 500 * nm
M = 24  # samples per lenslet side in the 3 x 3 focusing set-up
N_F = 2  # Fresnel number D^2 / (lambda f) of one lenslet: an integer (see the focal-peak test)
SIDE = M * um
FOCAL = SIDE**2 / (N_F * WAVELENGTH)  # 576 um


LAYOUTS = {
    "touching squares": square_grid(SIDE, FOCAL, count=3, shape="square"),
    "touching squares, sub-pixel offset": square_grid(SIDE, FOCAL, count=3, shape="square", offset=(0.3 * um, -0.4 * um)),
    "touching circles": square_grid(SIDE, FOCAL, count=3),
    "touching hex circles": hex_grid(SIDE, FOCAL, rings=1),
    "touching hex circles, offset": hex_grid(SIDE, FOCAL, rings=1, offset=(0.5 * um, 0.25 * um)),
}  # fmt: skip


@pytest.mark.parametrize("periodic", [False, True], ids=["cropped", "periodic"])
@pytest.mark.parametrize("antialias", [False, True], ids=["binary", "antialiased"])
@pytest.mark.parametrize("name", list(LAYOUTS))
def test_transmission_never_exceeds_one(name, antialias, periodic):
    # Touching lenslets partition the plane: no sample transmits more than the incident field.
    # The periodic window (72 um) is exactly the square array's extent, so its outer edges meet too.
    t = mla_transmission(
        LAYOUTS[name], Grid(3 * M, 1 * um), WAVELENGTH, antialias=antialias, periodic=periodic,
        dtype=torch.complex128,
    )  # fmt: skip
    assert float(t.abs().max()) <= 1.0 + 1e-12
    assert float(t.abs().max()) > 0.99  # the lenslets are there


def _focal_amplitude(
    t: torch.Tensor, grid: Grid, center: tuple[float, float], focal: float, *, periodic: bool = False
) -> float:
    """|U| at a lenslet's focus: the Fresnel integral of ``t`` (unit plane wave) as a direct sum.

    ``U(x0) = 1 / (lambda f) sum t(x) exp(j k |x - x0|^2 / (2 f)) dA`` (the constant phase
    factors drop out of the magnitude); independent of the engine's propagators.
    ``periodic``: ``x - x0`` is taken as the nearest periodic image (window = one period).
    """
    y, x = (a.numpy() for a in grid.axes())
    dy, dx = grid.spacing
    ox, oy = x[None, :] - center[0], y[:, None] - center[1]
    if periodic:
        width, height = grid.nx * dx, grid.ny * dy
        ox, oy = (ox + width / 2) % width - width / 2, (oy + height / 2) % height - height / 2
    k = 2 * math.pi / WAVELENGTH
    r2 = ox**2 + oy**2
    total = (t.numpy() * np.exp(1j * k * r2 / (2 * focal))).sum() * dx * dy
    return abs(total) / (WAVELENGTH * focal)


@pytest.mark.parametrize(
    ("antialias", "periodic"), [(False, True), (True, True), (True, False)],
    ids=["binary-periodic", "antialiased-periodic", "antialiased-cropped"],
)  # fmt: skip
def test_three_by_three_focal_peak_equals_single_lenslet_closed_form(antialias, periodic):
    # Closed form: at its focus a square lenslet of side D gives |U| = D^2 / (lambda f) = N_F.
    # A neighbour at distance D adds D^2 / (lambda f) sinc(N_F) (its field at the focus is the
    # Fourier transform of its aperture at frequency D / (lambda f)), which vanishes for an
    # integer N_F: so the centre lenslet of the 3 x 3 array must show the single-lens peak.
    # Edges fall on samples (centres on pixels); the shared-edge samples decide the result
    # (counted twice, the peak came out 17 % too high). The sampled sums are exact here: the
    # own term counts D^2 / dA (edge samples at 1/2, corners at 1/4) and each neighbour's sum
    # is a trapezoid rule over N_F whole periods of a linear phase, which is exactly 0.
    # A binary mask counts a sample on an *outer* rim whole (rim-inclusive, no neighbour to
    # share it), so the binary case is checked in a periodic window of exactly the array's
    # extent, where every edge is shared.
    grid = Grid(3 * M if periodic else 3 * M + 8, 1 * um)
    t = mla_transmission(
        LAYOUTS["touching squares"], grid, WAVELENGTH, antialias=antialias, periodic=periodic,
        dtype=torch.complex128,
    )  # fmt: skip
    amplitude = _focal_amplitude(t, grid, (0.0, 0.0), FOCAL, periodic=periodic)
    assert amplitude**2 == pytest.approx(N_F**2, rel=1e-9)


def test_sub_pixel_offset_focal_peak_is_close_to_the_closed_form():
    # With a sub-pixel offset the edges fall between samples; the antialiased (exact-area)
    # sum and the binary one approximate the same integral (measured 0.1 % and 1.4 %).
    grid = Grid(3 * M + 8, 1 * um)
    mla = LAYOUTS["touching squares, sub-pixel offset"]
    centre = mla[4].center
    assert centre == pytest.approx((0.3 * um, -0.4 * um))
    for antialias, rel in ((True, 0.005), (False, 0.05)):
        t = mla_transmission(mla, grid, WAVELENGTH, antialias=antialias, dtype=torch.complex128)
        assert _focal_amplitude(t, grid, centre, FOCAL) ** 2 == pytest.approx(N_F**2, rel=rel)


def test_huge_lenslet_on_a_one_row_grid():
    # Item 2: a 15,000-sample lenslet on a 1 x 64 grid (the patch was 30,003^2 samples).
    # Expected: the lens formula on the row, by brute force.
    grid = Grid((1, 64), 1 * um)
    focal = 0.1  # Nyquist at the rim: lambda f / (2 dx) = 25 mm > 7.5 mm
    mla = MicrolensArray((Lenslet((3.0 * um, 0.0), 15000 * um, focal),))
    t = mla_transmission(mla, grid, WAVELENGTH, dtype=torch.complex128)
    x = grid.axes()[1].numpy() - 3.0 * um
    expected = np.exp(-1j * (2 * math.pi / WAVELENGTH) * x**2 / (2 * focal))
    np.testing.assert_allclose(t.numpy()[0], expected, rtol=0, atol=1e-12)


def test_periodic_window_wraps_lenslets_cut_by_the_edge():
    # Item 3: a 2 x 2 array filling a 64 um window, shifted by whole pixels, must equal the
    # unshifted (uncut, cropped-path) transmission rolled by the same shift.
    grid = Grid(64, 1 * um)
    pitch, diameter, focal = 32 * um, 28 * um, 400 * um
    centred = square_grid(pitch, focal, count=2, aperture_fraction=diameter / pitch)
    shifted = square_grid(pitch, focal, count=2, aperture_fraction=diameter / pitch, offset=(7 * um, -5 * um))
    reference = mla_transmission(centred, grid, WAVELENGTH, dtype=torch.complex128)
    wrapped = mla_transmission(shifted, grid, WAVELENGTH, periodic=True, dtype=torch.complex128)
    torch.testing.assert_close(
        wrapped, torch.roll(reference, shifts=(-5, 7), dims=(0, 1)), rtol=0, atol=1e-12
    )
    # The cropped window loses part of the cut lenslet's focal peak; the periodic one keeps it.
    cropped = mla_transmission(shifted, grid, WAVELENGTH, dtype=torch.complex128)
    cut = max(shifted, key=lambda lens: lens.center[0] - lens.center[1]).center  # (23, -21) um: cut twice
    uncut = (cut[0] - 7 * um, cut[1] + 5 * um)
    full = _focal_amplitude(reference, grid, uncut, focal, periodic=True)
    assert _focal_amplitude(wrapped, grid, cut, focal, periodic=True) == pytest.approx(full, rel=1e-9)
    assert _focal_amplitude(cropped, grid, cut, focal, periodic=True) < 0.9 * full


def test_periodic_rejects_a_lenslet_wider_than_the_window():
    mla = MicrolensArray((Lenslet((0.0, 0.0), 40 * um, 1e-3),))
    with pytest.raises(ValueError, match="periodic=True needs every lenslet to fit"):
        mla_transmission(mla, Grid(32, 1 * um), WAVELENGTH, periodic=True)
