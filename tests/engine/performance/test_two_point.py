"""Two-point resolution on synthetic PSFs with closed-form answers.

References: two Gaussians of standard deviation sigma separated by d give the profile
``g(x) + g(x - d)``; the dip ratio (midpoint over maximum) is computed here from the
continuous function with scipy (independent of the code under test). Sparrow: the dip
appears at ``d = 2 sigma`` exactly (the midpoint curvature ``d^2/(4 sigma^2) - 1``
changes sign). Rayleigh: two Airy patterns ``0.61 lambda / NA`` apart dip to 0.7358
(the criterion's 0.735).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.optimize import brentq, minimize_scalar
from scipy.special import j1

from lfm_studio.engine.performance import RAYLEIGH_DIP, two_point_axial, two_point_lateral
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.units import nm, um

PIXEL, MAGNIFICATION = 6.5 * um, 10.0
SAMPLE = PIXEL / MAGNIFICATION


def spots(depths_um, *, sigma=4.0, n=96, centres=((0.3, -0.2),), shifts=(0.0,)):
    """Gaussian spots at ``centres`` (row, col offsets from the middle); spot i moves ``shifts[i]`` px/um in x."""
    y = torch.arange(n, dtype=torch.float64)[:, None] - n // 2
    x = torch.arange(n, dtype=torch.float64)[None, :] - n // 2
    data = torch.zeros(len(depths_um), n, n, dtype=torch.float64)
    for k, z in enumerate(depths_um):
        for (cy, cx), rate in zip(centres, shifts, strict=True):
            data[k] += torch.exp(-((x - cx - rate * z) ** 2 + (y - cy) ** 2) / (2 * sigma**2))
    return PSFStack(data, tuple(z * um for z in depths_um), PIXEL, MAGNIFICATION, 500 * nm)


def gaussian_pair_separation(sigma: float, threshold: float) -> float:
    """Separation (same unit as sigma) at which two Gaussians dip to ``threshold`` of their maximum."""

    def ratio(d):
        f = lambda x: math.exp(-(x**2) / (2 * sigma**2)) + math.exp(-((x - d) ** 2) / (2 * sigma**2))  # noqa: E731
        peak = -minimize_scalar(
            lambda x: -f(x), bounds=(-sigma, d / 2), method="bounded", options={"xatol": 1e-12}
        ).fun
        return f(d / 2) / peak

    return brentq(lambda d: ratio(d) - threshold, 2.0 * sigma * (1 + 1e-9), 10 * sigma, xtol=1e-12)


def test_lateral_two_point_of_a_gaussian_matches_the_closed_form_dip():
    # Interpolation budget (test_measured): ~3e-4 of the peak near the dip; measured 3e-4 at sigma 4 px.
    expected = gaussian_pair_separation(4.0, RAYLEIGH_DIP) * SAMPLE  # 2.80 sigma
    assert two_point_lateral(spots([0.0])) == pytest.approx(expected, rel=2e-3)


def test_lateral_two_point_near_the_sparrow_limit_is_two_sigma():
    # A dip of 1e-6 appears (1 + 8e-4) x 2 sigma apart (the dip grows as (d - 2 sigma)^2); measured 8e-4.
    assert two_point_lateral(spots([0.0]), threshold=1 - 1e-6) == pytest.approx(2 * 4.0 * SAMPLE, rel=2e-3)


def test_lateral_two_point_of_an_airy_pattern_is_the_rayleigh_distance():
    # [2 J1(v)/v]^2 with 6 px per FWHM: the first zero v = 3.8317 is the Rayleigh distance 0.61 lambda/NA.
    # The criterion 0.735 (vs 0.7358) and interpolation put it 9e-4 off; tolerance 3e-3.
    scale = 2 * 1.616340 / 6.0  # v per pixel
    n = 96
    y, x = np.mgrid[:n, :n] - n // 2
    v = np.maximum(np.hypot(x - 0.25, y + 0.1) * scale, 1e-12)
    psf = PSFStack(torch.from_numpy((2 * j1(v) / v) ** 2)[None], (0.0,), PIXEL, MAGNIFICATION, 500 * nm)
    assert two_point_lateral(psf) == pytest.approx(3.831706 / scale * SAMPLE, rel=3e-3)


def test_axial_two_point_of_a_spot_moving_with_depth():
    # 0.5 px/um of parallax: the pair resolves when the images are d* px apart, dz = d* / 0.5 um.
    # Depth samples every 0.5 um, linear interpolation of the dip ratio between them; measured 3e-4.
    depths = [0.5 * k for k in range(-10, 61)]  # resolves near 22 um
    expected = gaussian_pair_separation(4.0, RAYLEIGH_DIP) / 0.5 * um
    assert two_point_axial(spots(depths, shifts=(0.5,)), depth=0.0) == pytest.approx(expected, rel=2e-3)


def test_axial_pairs_without_parallax_never_resolve():
    # The spot only dims with depth and stays in place: two emitters on the axis overlap exactly.
    depths = [float(k) for k in range(-10, 11)]
    psf = spots(depths)
    psf = psf.with_data(
        psf.data * torch.exp(-(torch.tensor(depths, dtype=torch.float64) ** 2) / 50)[:, None, None]
    )
    assert two_point_axial(psf, depth=0.0) is None


def test_axial_pair_is_resolved_by_the_view_with_the_largest_parallax():
    # Three views: on-axis (no parallax), 0.25 and 1.0 px/um; the fastest one decides (the slow one
    # would give 4x the separation). Depth steps 0.25 um; measured 3e-4.
    depths = [0.25 * k for k in range(-4, 61)]  # resolves near 11 um
    psf = spots(depths, centres=((0.3, -0.2), (0.1, -30.0), (0.2, 30.0)), shifts=(0.0, 0.25, 1.0))
    expected = gaussian_pair_separation(4.0, RAYLEIGH_DIP) / 1.0 * um
    assert two_point_axial(psf, depth=0.0) == pytest.approx(expected, rel=5e-3)


# -- dip_ratio: the two maxima nearest the emitters (issue 22, item 8) --------------------
def _dense_reference(f, a: float, b: float) -> float:
    """Dip ratio by dense numpy sampling: the local maxima (scipy find_peaks) nearest a and b."""
    from scipy.signal import find_peaks

    t = np.linspace(a - 3.0, b + 3.0, 200_001)
    y = f(t)
    peaks, _ = find_peaks(y)
    p1, p2 = int(peaks[np.argmin(abs(t[peaks] - a))]), int(peaks[np.argmin(abs(t[peaks] - b))])
    if p1 == p2:
        return 1.0
    return float(y[p1 : p2 + 1].min() / min(y[p1], y[p2]))


def _pair(h2: float, w2: float, s: float):
    """A unit Gaussian (variance 9) at 0 plus one of height ``h2``, variance ``w2`` at ``s``."""
    return lambda t: np.exp(-(t**2) / 18) + h2 * np.exp(-((t - s) ** 2) / (2 * w2))


def test_dip_between_a_bright_shoulder_and_a_dim_narrow_peak():
    from lfm_studio.engine.performance.two_point import dip_ratio

    # The profile: peaks ~1.0 and ~0.44, dip ~0.66 of the smaller (taking the maximum of
    # each half gave 1.0, "no dip").
    def f(t):
        return np.exp(-(t**2) / 18) + 0.3 * np.exp(-((t - 6) ** 2) / 0.5)

    expected = _dense_reference(f, 0.0, 6.0)
    assert 0.5 < expected < 0.8  # a real dip
    ratio = dip_ratio(lambda t: torch.as_tensor(f(t.numpy())), 0.0, 6.0)
    assert ratio == pytest.approx(expected, rel=2e-3)


@pytest.mark.parametrize(
    ("h2", "w2", "s"), [(0.3, 0.5, 6.0), (0.6, 2.0, 7.0), (2.0, 1.0, 8.0), (0.5, 9.0, 9.0)]
)
def test_dip_ratio_with_unequal_heights_and_widths(h2, w2, s):
    from lfm_studio.engine.performance.two_point import dip_ratio

    f = _pair(h2, w2, s)
    expected = _dense_reference(f, 0.0, s)
    assert dip_ratio(lambda t: torch.as_tensor(f(t.numpy())), 0.0, s) == pytest.approx(expected, rel=2e-3)


def test_dip_ratio_of_equal_gaussians_and_a_single_maximum():
    from lfm_studio.engine.performance.two_point import dip_ratio

    for s in (2.5, 3.0, 4.0):
        f = lambda t, s=s: np.exp(-(t**2) / 2) + np.exp(-((t - s) ** 2) / 2)  # noqa: E731
        # Symmetric: the dip is at the midpoint, 2 exp(-s^2 / 8); the maxima from dense sampling.
        t = np.linspace(-1.0, s + 1.0, 200_001)
        expected = 2 * math.exp(-(s**2) / 8) / f(t).max()
        assert dip_ratio(lambda x, f=f: torch.as_tensor(f(x.numpy())), 0.0, s) == pytest.approx(
            expected, rel=1e-4
        )
    # Below Sparrow (s < 2 sigma = 2) the sum has one maximum: not resolved.
    f = lambda t: np.exp(-(t**2) / 2) + np.exp(-((t - 1.5) ** 2) / 2)  # noqa: E731
    assert dip_ratio(lambda x: torch.as_tensor(f(x.numpy())), 0.0, 1.5) == 1.0
    # A dim peak swallowed by the bright one's shoulder (no local maximum of its own): not resolved.
    f = _pair(0.05, 1.0, 3.0)
    assert _dense_reference(f, 0.0, 3.0) == 1.0
    assert dip_ratio(lambda x: torch.as_tensor(f(x.numpy())), 0.0, 3.0) == 1.0
