"""Measured metrics on synthetic PSF stacks whose widths are known in closed form.

Error budget common to these tests: widths are read from the 4-point Lagrange
interpolant of point-sampled curves. Its error is about ``f'''' h^4 / 43`` of the peak
(``0.5625 / 24`` times the 4th derivative), i.e. 3e-4 of the peak for a Gaussian with
sigma = 4 samples, moving a half-maximum crossing by about 2e-3 samples; a FWHM of
9.4 samples is therefore good to about 4e-4 relative. Tolerances are a few times the
budget so the tests can fail on real mistakes (a lost factor, the wrong pixel size,
a wrong reference slice), not on rounding.
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
import torch
from scipy.special import j1

from lfm_studio.engine.performance import (
    axial_fwhm,
    best_focus_index,
    lateral_fwhm,
    measured_depth_of_field,
)
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.units import nm, um

FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
PIXEL = 6.5 * um
MAGNIFICATION = 10.0  # sample pixel 0.65 um


def gaussian_slices(depths_um, *, sigma, n=64, centre=(0.3, -0.2), shift_per_um=0.0, amplitude=None):
    """``(Z, n, n)`` Gaussian spots (sigma in pixels, or a function of depth in um), point-sampled."""
    y = torch.arange(n, dtype=torch.float64)[:, None] - n // 2
    x = torch.arange(n, dtype=torch.float64)[None, :] - n // 2
    slices = []
    for z in depths_um:
        s = sigma(z) if callable(sigma) else sigma
        a = 1.0 if amplitude is None else amplitude(z)
        cx = centre[1] + shift_per_um * z
        slices.append(a * torch.exp(-((x - cx) ** 2 + (y - centre[0]) ** 2) / (2 * s * s)))
    return torch.stack(slices)


def stack(data, depths_um):
    return PSFStack(data, tuple(z * um for z in depths_um), PIXEL, MAGNIFICATION, 500 * nm)


def test_lateral_fwhm_of_a_sampled_gaussian():
    psf = stack(gaussian_slices([0.0], sigma=4.0), [0.0])
    expected = FWHM_PER_SIGMA * 4.0 * PIXEL / MAGNIFICATION  # 6.12 um in the sample
    # Budget 4e-4 (module docstring); measured 2.6e-4.
    assert lateral_fwhm(psf) == pytest.approx(expected, rel=1e-3)


def test_lateral_fwhm_of_a_sampled_airy_pattern():
    # Airy intensity [2 J1(v)/v]^2, v = 2 pi NA r / lambda: half maximum at v = 1.61634, FWHM 0.51456 lambda/NA.
    # 6 samples per FWHM (4th derivative of the core comparable to a Gaussian's); measured 5.2e-4.
    fwhm_px = 6.0
    scale = 2 * 1.616340 / fwhm_px  # v per pixel
    n = 64
    y, x = np.mgrid[:n, :n] - n // 2
    v = np.hypot(x - 0.25, y + 0.1) * scale
    airy = np.where(v == 0, 1.0, (2 * j1(np.maximum(v, 1e-12)) / np.maximum(v, 1e-12)) ** 2)
    psf = stack(torch.from_numpy(airy)[None], [0.0])
    assert lateral_fwhm(psf) == pytest.approx(fwhm_px * PIXEL / MAGNIFICATION, rel=2e-3)


def test_axial_fwhm_peak_method_reads_the_known_axial_profile():
    # Spot brightness exp(-z^2 / (2 * 5^2)) versus depth: FWHM 11.774 um; 1 um depth steps
    # (5 samples per sigma: Lagrange error ~1e-4); measured 3e-5.
    depths = [float(z) for z in range(-20, 21)]
    data = gaussian_slices(depths, sigma=3.0, amplitude=lambda z: math.exp(-(z**2) / 50.0))
    assert axial_fwhm(stack(data, depths), method="peak") == pytest.approx(
        FWHM_PER_SIGMA * 5.0 * um, rel=1e-3
    )


def test_axial_fwhm_correlation_of_a_spot_moving_with_depth():
    # Spot (sigma 3 px) moving 0.5 px/um: normalised correlation exp(-(0.5 z)^2 / (4 sigma^2)) falls to 1/2
    # at |z| = 2 sigma sqrt(ln 2) / 0.5, FWHM 19.98 um. Point-sampled Gaussians with sigma 3 px correlate
    # like continuous ones to 1e-12 (aliasing of exp(-2 pi^2 sigma^2 f^2) at f = 1 px^-1); the
    # half-level crossing of c(z) on 1 um depth samples adds ~1e-6; measured 3.4e-7.
    depths = [float(z) for z in range(-20, 21)]
    psf = stack(gaussian_slices(depths, sigma=3.0, shift_per_um=0.5), depths)
    expected = 4 * 3.0 * math.sqrt(math.log(2.0)) / 0.5 * um
    assert axial_fwhm(psf, depth=0.0) == pytest.approx(expected, rel=1e-4)


def test_depth_order_of_the_slices_does_not_matter():
    depths = [float(z) for z in range(-20, 21)]
    data = gaussian_slices(depths, sigma=3.0, shift_per_um=0.5)
    order = list(range(len(depths)))
    random.Random(3).shuffle(order)
    shuffled = stack(data[order], [depths[i] for i in order])
    assert axial_fwhm(shuffled, depth=0.0) == pytest.approx(
        axial_fwhm(stack(data, depths), depth=0.0), rel=1e-12
    )


def test_best_focus_is_the_sharpest_slice_not_the_first():
    depths = [float(z) for z in range(-10, 11)]
    psf = stack(gaussian_slices(depths, sigma=lambda z: 2.0 + 0.2 * abs(z - 3.0)), depths)
    assert psf.depths[best_focus_index(psf)] == pytest.approx(3.0 * um)


def test_depth_of_field_of_a_gaussian_beam_is_twice_its_rayleigh_range():
    # sigma(z) = sigma0 sqrt(1 + (z / z_R)^2): the FWHM reaches sqrt(2) x its best at |z| = z_R = 8 um,
    # so DoF = 16 um. Edges are linear interpolations of the FWHM between 1 um depth samples
    # (curvature error ~ h^2 w'' / 8 / w' = 0.1 um at most, measured 0.02 um).
    depths = [float(z) for z in range(-20, 21)]
    psf = stack(gaussian_slices(depths, sigma=lambda z: 3.0 * math.sqrt(1 + (z / 8.0) ** 2)), depths)
    dof = measured_depth_of_field(psf)
    assert dof.depth_of_field == pytest.approx(16 * um, abs=0.1 * um)
    assert dof.depth_range == pytest.approx((-8 * um, 8 * um), abs=0.05 * um)
    assert not dof.truncated
    # sigma 3 px: (4/3)^4 = 3x the budget of sigma 4 px, 1.2e-3; measured 9e-4.
    assert dof.best_fwhm == pytest.approx(FWHM_PER_SIGMA * 3.0 * PIXEL / MAGNIFICATION, rel=2e-3)


def test_depth_of_field_cut_off_by_the_stack_is_flagged_as_a_lower_bound():
    depths = [float(z) for z in range(-5, 6)]
    psf = stack(gaussian_slices(depths, sigma=lambda z: 3.0 * math.sqrt(1 + (z / 8.0) ** 2)), depths)
    dof = measured_depth_of_field(psf)
    assert dof.truncated
    assert dof.depth_of_field == pytest.approx(10 * um)


def test_two_focus_groups_add_their_depth_ranges():
    # Two spots focused at -15 and +15 um (z_R 3 um each): the sharper one sets the FWHM per slice.
    # 1 um depth samples against z_R = 3 um: edge error up to ~0.1 um each; measured 0.015 um in total.
    depths = [float(z) for z in range(-30, 31)]

    def sigma(z):
        return 3.0 * min(math.sqrt(1 + ((z + 15) / 3.0) ** 2), math.sqrt(1 + ((z - 15) / 3.0) ** 2))

    dof = measured_depth_of_field(stack(gaussian_slices(depths, sigma=sigma), depths))
    assert dof.depth_of_field == pytest.approx(12 * um, abs=0.2 * um)  # 2 x 2 z_R
    assert dof.depth_range == pytest.approx((-18 * um, 18 * um), abs=0.1 * um)


def test_batched_stacks_are_refused_with_a_fix():
    data = gaussian_slices([0.0], sigma=3.0)[None].expand(2, 1, 64, 64)
    psf = PSFStack(data, (0.0,), PIXEL, MAGNIFICATION, 500 * nm)
    with pytest.raises(ValueError, match=r"\(Z, Y, X\).*Fix"):
        lateral_fwhm(psf)
