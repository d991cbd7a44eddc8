"""Closed-form metrics against values computed by hand from the presets' parameters.

Each expected value below is written out from the preset's numbers (not from the code
under test), so a wrong formula, unit or lenslet selection fails. Tolerances are
rel=1e-9 (float rounding of the unit conversions only) unless stated.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lfm_studio.engine.design import DesignWarning, MLASpec, evolve, load_preset
from lfm_studio.engine.performance import closed_form_metrics
from lfm_studio.engine.performance.fourier_closed_forms import focus_depth, union_length
from lfm_studio.engine.units import mm, um

EXACT = 1e-9


def test_guo2019_flfm_matches_hand_values():
    m = closed_form_metrics(load_preset("flfm_guo2019"))
    # 40x/0.95 air, f_F 75 mm, 3 x 3 square lenslets 600 um, d = f_MLA = 16.8 mm, 6.5 um pixels, 680 nm.
    assert m.magnification == pytest.approx(40 * 16.8 / 75, rel=EXACT)  # 8.96
    assert m.number_of_views == 9
    pupil = 2 * 0.95 * 75 * mm / 40  # 3.5625 mm
    assert m.views_across == pytest.approx(pupil / (600 * um), rel=EXACT)  # N = 5.94
    assert m.effective_numerical_aperture == pytest.approx(0.95 * 600 * um / pupil, rel=EXACT)  # 0.16
    # Rayleigh 0.61 lambda / NA_eff (thesis 3.3.1; the default criterion)
    assert m.lateral_criterion == "rayleigh"
    assert m.lateral_resolution_diffraction == pytest.approx(0.61 * 0.68 * um / 0.16, rel=EXACT)  # 2.5925 um
    assert m.lateral_resolution_sampling == pytest.approx(2 * 6.5 * um / 8.96, rel=EXACT)  # 1.45 um
    assert m.lateral_resolution == pytest.approx(2.5925 * um, rel=EXACT)

    # Eq. 3.24 (n = 1): best view is a corner lenslet (r = 600 sqrt 2 um); mean over the 8 off-axis views.
    def dz(r):
        return 1.22 * 680e-9 * (75 * mm) ** 2 / (600 * um * r * 40**2)

    assert m.axial_resolution == pytest.approx(dz(600 * math.sqrt(2) * um), rel=EXACT)  # 5.73 um
    assert m.axial_resolution_mean == pytest.approx(
        (4 * dz(600 * um) + 4 * dz(600 * math.sqrt(2) * um)) / 8, rel=EXACT
    )
    # Inoue with NA_eff: lambda / NA_eff^2 + delta / (M_T NA_eff) = 26.56 + 4.53 um.
    dof = 0.68 * um / 0.16**2 + 6.5 * um / (8.96 * 0.16)
    assert m.depth_of_field == pytest.approx(dof, rel=EXACT)
    assert m.depth_range == pytest.approx((-dof / 2, dof / 2), rel=EXACT)
    # The 2.66 mm field stop (66.5 um) is tighter than the lenslet spacing (600 um / 8.96 = 67.0 um).
    assert m.field_of_view == pytest.approx(2.66 * mm / 40, rel=EXACT)
    assert m.field_of_view_limit == "field stop"


def test_guo2019_field_of_view_without_field_stop_is_the_papers_67_um():
    # Guo et al. 2019: FOV = d_MLA f_FL / (M f_MLA) = 600 um x 75 / (40 x 16.8) = 66.96 um ("67 um").
    with pytest.warns(DesignWarning, match="sub-images overlap"):  # the field number alone lets them overlap
        design = evolve(load_preset("flfm_guo2019"), "relay.field_stop_diameter_mm", None)
    m = closed_form_metrics(design)
    assert m.field_of_view_limit == "lenslet spacing"
    assert m.field_of_view == pytest.approx(600 * um * 75 / (40 * 16.8), rel=EXACT)
    assert m.field_of_view == pytest.approx(67 * um, rel=0.005)  # the paper rounds to 67 um


def test_xlfm_cong2017_matches_hand_values():
    m = closed_form_metrics(load_preset("xlfm_cong2017"))
    # 20x/1.0 water (n 1.333), f_F 160 mm, d 27.25 mm, 27 lenslets of 1 mm aperture (26 / 28.5 mm).
    m_t = 20 * 27.25 / 160
    assert m.magnification == pytest.approx(m_t, rel=EXACT)  # 3.406
    assert m.number_of_views == 27  # all inside the 16 mm pupil image
    assert m.effective_numerical_aperture == pytest.approx(1.0 * 1.0 / 16.0, rel=EXACT)
    assert m.lateral_resolution == pytest.approx(0.61 * 0.525 * um / 0.0625, rel=EXACT)  # 5.124 um > 3.82 um
    r_max = math.hypot(2200, 5080.682369) * um  # outermost lenslet centre
    best = 1.22 * 525e-9 * 1.333 * (160 * mm) ** 2 / (1 * mm * r_max * 20**2)
    assert m.axial_resolution == pytest.approx(best, rel=EXACT)  # 9.87 um
    # Two groups focused at z_f = n f_F^2 (1/d - 1/f) / M^2: -150.5 um (f 26) and +137.3 um (f 28.5).
    z26 = 1.333 * (160 * mm) ** 2 / 400 * (1 / (27.25 * mm) - 1 / (26 * mm))
    z285 = 1.333 * (160 * mm) ** 2 / 400 * (1 / (27.25 * mm) - 1 / (28.5 * mm))
    assert z26 == pytest.approx(-150.5 * um, abs=0.1 * um) and z285 == pytest.approx(137.3 * um, abs=0.1 * um)
    dof1 = 0.525 * um * 1.333 / 0.0625**2 + 1.333 * 6.5 * um / (m_t * 0.0625)  # 220 um per group
    assert m.depth_range == pytest.approx((z26 - dof1 / 2, z285 + dof1 / 2), rel=EXACT)
    assert m.depth_of_field == pytest.approx(2 * dof1, rel=EXACT)  # the two ranges do not overlap
    assert m.field_of_view == pytest.approx(12.9 * mm / 20, rel=EXACT)  # 645 um field stop


def test_conventional_10x_matches_levoy_hand_values():
    m = closed_form_metrics(load_preset("lfm_10x_na03"))
    # 10x/0.3 air, p 125 um, d 1.875 mm, 6.5 um pixels, 525 nm.
    pupil_image = 2 * 1.875 * mm * math.tan(math.asin(0.3 / 10))  # 112.6 um < pitch: a disc
    spot = 0.94 * 525e-9 * 1.875 * mm / (125 * um)  # lenslet Sparrow spot 7.40 um > 6.5 um pixel
    n_u = pupil_image / spot  # 15.2 (Levoy's W / R_obj)
    assert m.views_across == pytest.approx(n_u, rel=EXACT)
    assert m.number_of_views == math.floor(math.pi / 4 * n_u**2)  # 181
    assert m.magnification == 10.0
    assert m.lateral_resolution == pytest.approx(12.5 * um, rel=EXACT)  # pitch / M
    axial = 0.525 * um / 0.09 + 125 * um / (10 * 0.3)  # 47.5 um (Levoy's refocused depth of field)
    assert m.axial_resolution == pytest.approx(axial, rel=EXACT)
    assert m.depth_of_field == pytest.approx(n_u * axial, rel=EXACT)  # 722 um
    assert m.field_of_view == pytest.approx(106 * 125 * um / 10, rel=EXACT)  # MLA 13.25 mm < sensor 13.31 mm
    assert m.field_of_view_limit == "MLA extent"


def test_conventional_prevedel_is_f_number_matched_and_levoy_n_u_holds():
    m = closed_form_metrics(load_preset("lfm_prevedel2014"))
    # f-number matched: the pupil image fills the 150 um lenslet, so N_u = p NA / (0.47 lambda M) (Levoy 2006).
    assert m.views_across == pytest.approx(150 * um * 0.5 / (0.47 * 525e-9 * 20), rel=EXACT)  # 15.2
    assert m.lateral_resolution == pytest.approx(7.5 * um, rel=EXACT)
    assert m.field_of_view == pytest.approx(88 * 150 * um / 20, rel=EXACT)  # 660 um (thesis table: 700 um)


def test_conventional_prevedel_views_cover_the_disc_not_the_square_lenslet():
    # f-number matched: the 150.05 um pupil image just reaches the sides of the 150 um square
    # lenslet but not its corners, so it covers about pi/4 of it (walk-through 6: 230 views before).
    m = closed_form_metrics(load_preset("lfm_prevedel2014"))
    radius = 3 * mm * math.tan(math.asin(0.5 / 20))  # 75.03 um
    spot = 0.94 * 525e-9 * 3 * mm / (150 * um)  # lenslet Sparrow spot 9.87 um > 6.5 um pixel
    side = np.linspace(-75 * um, 75 * um, 1501)  # sample the lenslet, count the points the disc covers
    x, y = np.meshgrid(side, side)
    covered = np.mean(np.hypot(x, y) <= radius) * (150 * um) ** 2
    assert m.number_of_views == pytest.approx(covered / spot**2, abs=1)  # 181, as 10x/0.3


@pytest.mark.filterwarnings("ignore::lfm_studio.engine.design.DesignWarning")  # overlapping sub-images
@pytest.mark.parametrize("na", [0.5, 0.6, 0.75])
def test_conventional_views_are_the_pixels_behind_a_lenslet_that_the_pupil_image_covers(na):
    # 10 um pixels (coarser than the 9.87 um lenslet spot): a view per pixel (thesis 1.1.1: a view is the
    # same pixel behind every lenslet). 15 x 15 pixels per 150 um lenslet; count those whose centre lies in
    # the pupil image: inside the sides (NA 0.5), past the sides (0.6) or past the corners (0.75: all 225).
    design = evolve(load_preset("lfm_prevedel2014"), "camera.pixel_pitch_um", 10.0)
    m = closed_form_metrics(evolve(design, "objective.numerical_aperture", na))
    radius = 3 * mm * math.tan(math.asin(na / 20))
    centres = (np.arange(15) - 7) * 10 * um
    x, y = np.meshgrid(centres, centres)
    pixels = int(np.count_nonzero(np.hypot(x, y) <= radius))
    assert m.number_of_views == pytest.approx(pixels, abs=2)


@pytest.mark.filterwarnings("ignore::lfm_studio.engine.design.DesignWarning")  # overlapping sub-images
def test_conventional_views_behind_a_round_lenslet_stop_at_its_rim():
    # As above at NA 0.75 (pupil image 225 um) but round 150 um lenslets: only the pixels whose centre
    # lies within 75 um of the lenslet centre see light.
    design = evolve(load_preset("lfm_prevedel2014"), "camera.pixel_pitch_um", 10.0)
    design = evolve(evolve(design, "objective.numerical_aperture", 0.75), "mla.lenslet_shape", "circle")
    centres = (np.arange(15) - 7) * 10 * um
    x, y = np.meshgrid(centres, centres)
    pixels = int(np.count_nonzero(np.hypot(x, y) <= 75 * um))
    assert closed_form_metrics(design).number_of_views == pytest.approx(pixels, abs=2)


def test_focus_depth_is_zero_for_a_camera_at_the_focal_plane_and_changes_sign_across_it():
    design = load_preset("flfm_guo2019")
    assert focus_depth(design, 16.8 * mm) == 0.0
    assert focus_depth(design, 16.0 * mm) < 0.0 < focus_depth(design, 17.5 * mm)


def test_union_length_merges_overlapping_intervals():
    assert union_length([(0.0, 2.0), (1.0, 3.0), (5.0, 6.0)]) == pytest.approx(4.0)
    assert union_length([(0.0, 4.0), (1.0, 2.0)]) == pytest.approx(4.0)


def test_a_single_on_axis_lenslet_has_no_parallax_so_no_axial_resolution():
    lens = {
        "center_um": (0.0, 0.0),
        "aperture_diameter_um": 600.0,
        "focal_length_mm": 16.8,
        "shape": "square",
    }
    design = load_preset("flfm_guo2019").updated(mla=MLASpec(lenslets=(lens,)))
    m = closed_form_metrics(design)
    assert m.number_of_views == 1
    assert m.axial_resolution is None and m.axial_resolution_mean is None
    assert any("parallax" in note for note in m.notes)
    assert m.lateral_resolution == pytest.approx(0.61 * 0.68 * um / 0.16, rel=EXACT)


def test_conventional_with_an_explicit_lenslet_list_uses_its_aperture_and_extent():
    design = load_preset("lfm_10x_na03")
    small = design.updated(mla=MLASpec.square_grid(125.0, 20, 1.875, lenslet_shape="square"))
    a, b = closed_form_metrics(design), closed_form_metrics(small)
    assert b.lateral_resolution == pytest.approx(a.lateral_resolution, rel=EXACT)  # same 125 um pitch
    assert b.views_across == pytest.approx(a.views_across, rel=EXACT)
    assert b.field_of_view == pytest.approx(20 * 125 * um / 10, rel=EXACT)  # 2.5 mm array / 10x
    assert b.field_of_view_limit == "MLA extent"


def test_measuring_a_conventional_design_is_refused_with_the_reason():
    from lfm_studio.engine.performance import measurement_psf

    with pytest.raises(NotImplementedError, match=r"shift-invariant PSF per depth.*closed-form"):
        measurement_psf(load_preset("lfm_10x_na03"))


@pytest.mark.parametrize(
    ("criterion", "factor"), [("rayleigh", 1.22 / 2), ("abbe", 1 / 2), ("sparrow", 0.47)]
)
def test_lateral_criterion_sets_the_diffraction_limit(criterion, factor):
    # Fourier (Guo: NA_eff = 0.95 x 600 um / 3.5625 mm) and conventional (10x/0.3 at 525 nm) designs.
    guo = closed_form_metrics(load_preset("flfm_guo2019"), criterion=criterion)
    na_eff = 0.95 * 600 * um / (2 * 0.95 * 75 * mm / 40)
    assert guo.lateral_criterion == criterion
    assert guo.lateral_resolution_diffraction == pytest.approx(factor * 0.68 * um / na_eff, rel=EXACT)
    assert guo.lateral_resolution == pytest.approx(
        max(factor * 0.68 * um / na_eff, 2 * 6.5 * um / (40 * 16.8 / 75)), rel=EXACT
    )
    lfm = closed_form_metrics(load_preset("lfm_10x_na03"), criterion=criterion)
    design = load_preset("lfm_10x_na03")
    na, lam = design.objective.numerical_aperture, design.wavelength
    assert lfm.lateral_resolution_diffraction == pytest.approx(factor * lam / na, rel=EXACT)


def test_unknown_lateral_criterion_is_named():
    with pytest.raises(ValueError, match=r"criterion must be one of .*'rayleigh'.*got 'airy'"):
        closed_form_metrics(load_preset("flfm_guo2019"), criterion="airy")
