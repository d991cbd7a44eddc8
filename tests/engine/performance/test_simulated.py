"""Metrics measured on a simulated Fourier-LFM PSF agree with the physics they stand for.

The one real simulation of this package's tests (fixture ``guo_psf``): the Guo 2019
FLFM preset (3 x 3 square 600 um lenslets, d = 16.8 mm, 680 nm, 6.5 um pixels,
M_T = 8.96) on the depths ``lfm-studio info --measure`` uses.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from lfm_studio.engine.performance import closed_form_metrics, measurement_depths
from lfm_studio.engine.performance.psf_measures import spot_fwhm_pixels
from lfm_studio.engine.units import um


def test_measurement_depths_cover_the_focus_finely_and_the_depth_range_coarsely(guo_design, guo_psf):
    closed = closed_form_metrics(guo_design)
    fine, coarse = measurement_depths(guo_design)
    assert len(fine) == 11 and fine[5] == 0.0  # the Guo lenslets focus the native focal plane
    assert fine[1] - fine[0] == pytest.approx(closed.axial_resolution / 3)
    assert min(coarse) < closed.depth_range[0] and max(coarse) > closed.depth_range[1]
    assert sorted(guo_psf.depths) == sorted(fine + coarse)
    assert guo_psf.data.shape[-2:] == (296, 296)  # cropped to the lit region (+-900 um lenslets + spill)


def test_in_focus_spot_width_is_the_pixel_integrated_sinc_squared_of_a_square_lenslet(guo_psf):
    # A uniformly lit square lenslet (side D) gives sinc^2(x / a), a = lambda d / D = 19.04 um; a 6.5 um
    # pixel convolves it with a box: FWHM 17.31 um on the sensor (16.87 um unbinned). Budget: Lagrange
    # reading at 2.7 px per FWHM (~1 %) and the aplanatic pupil amplitude over the lenslet (< 0.5 %);
    # measured +1.0 %.
    a, p = 0.68 * 16.8 / 0.6, 6.5

    def box(x):
        u = np.linspace(x - p / 2, x + p / 2, 4001)
        return np.trapezoid(np.sinc(u / a) ** 2, u)

    expected = 2 * brentq(lambda x: box(x) - box(0.0) / 2, 0.1, a)
    index = guo_psf.depths.index(0.0)
    fx, fy = spot_fwhm_pixels(guo_psf.data[index])
    assert fx * p == pytest.approx(expected, rel=0.02)
    assert fy == pytest.approx(fx, rel=1e-6)  # square lenslet: same along x and y


def test_measured_resolution_and_depth_of_field_agree_with_the_closed_forms(guo_metrics):
    m = guo_metrics
    closed, measured = m.closed_form, m.measured
    assert measured.focus_depth == 0.0
    # Lateral: two sinc^2 spots dip to 0.735 a little beyond the Abbe distance lambda / (2 NA_eff) = 2.125 um
    # (a square pupil's sinc^2 dips only to 0.81 there), pixel integration widens more: measured +8 %,
    # below the Rayleigh closed form 0.61 lambda / NA_eff (the default criterion).
    assert closed.lateral_criterion == "rayleigh"
    abbe = closed.lateral_resolution_diffraction * 0.5 / 0.61
    assert abbe < measured.lateral_two_point < 1.15 * abbe
    assert measured.lateral_two_point < closed.lateral_resolution
    # Axial: eq. 3.24 uses the Rayleigh radius of a circular lenslet (1.22 lambda d / D); the corner views
    # of square lenslets move along their diagonal, where the spot is narrower: measured -19 %.
    assert measured.axial_two_point == pytest.approx(closed.axial_resolution, rel=0.25)
    # Depth of field: FWHM within sqrt(2) (measured 43 um) vs Inoue's lambda/NA_eff^2 + delta/(M_T NA_eff)
    # (31 um): two definitions of the same scale; they agree within a factor 1.5.
    assert closed.depth_of_field < measured.depth_of_field < 1.5 * closed.depth_of_field
    assert not measured.depth_of_field_truncated
    # The correlation width includes the central view (no parallax), so it exceeds the two-point value.
    assert measured.axial_fwhm > measured.axial_two_point
    assert measured.lateral_fwhm == pytest.approx(1.95 * um, rel=0.03)
    checks = [c for c in m.requirements if c.basis == "measured"]
    assert [c.quantity for c in checks] == ["depth_of_field", "lateral_resolution", "axial_resolution"]
