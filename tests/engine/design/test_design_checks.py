"""Design-level physics: Fourier pupil and sub-image geometry, sensor fit, sampling, f-number matching.

Reference values come from the published Fourier LFM of Guo et al. 2019 (Opt. Express 27, 25573):
40x/0.95, f_FL = 75 mm, d_MLA = 600 um, f_MLA = 16.8 mm, for which the paper gives the occupancy
ratio N = D_pupil / d_MLA = 5.9375 (Appendix B) and FOV = d_MLA f_FL / (f_MLA M) = 66.96 um (Appendix D).
All geometry is a few float64 operations: relative tolerance 1e-12 (round-off only).
"""

from __future__ import annotations

import math
import re

import pytest

from lfm_studio.engine.design import DesignWarning, LensletSpec, MLASpec, ObjectiveSpec, RelayLensSpec, evolve

from .conftest import make_conventional, make_fourier


def test_fourier_pupil_image_matches_guo_2019(fourier):
    # D_pupil(MLA) = 2 NA f_relay / M = 2 x 0.95 x 75 mm / 40 = 3.5625 mm; N = D / d_MLA = 5.9375.
    assert fourier.pupil_diameter_at_mla == pytest.approx(3.5625e-3, rel=1e-12)
    assert fourier.pupil_diameter_at_mla / 600e-6 == pytest.approx(5.9375, rel=1e-12)
    # Sample-to-sensor magnification M f_MLA / f_FL = 8.96 (camera at the lenslet focal plane).
    assert fourier.magnification == pytest.approx(40 * 16.8 / 75, rel=1e-12)


def test_fourier_sub_image_size_follows_the_field_stop(fourier):
    assert fourier.field_of_view_diameter == pytest.approx(2.66e-3 / 40, rel=1e-12)
    # A field stop of d_MLA f_FL / f_MLA at the NIP makes each sub-image exactly one lenslet wide,
    # i.e. the paper's FOV = d_MLA f_FL / (f_MLA M) = 66.96 um at the sample.
    matched = evolve(fourier, "relay.field_stop_diameter_mm", 0.6 * 75 / 16.8)
    assert 2 * matched.sub_image_radius == pytest.approx(600e-6, rel=1e-12)
    assert matched.field_of_view_diameter == pytest.approx(66.96428571428571e-6, rel=1e-12)
    # The objective's field number also limits the field: the smaller limit wins.
    narrow = evolve(fourier, "objective.field_number_mm", 2.0)
    assert narrow.field_of_view_diameter == pytest.approx(2.0e-3 / 40, rel=1e-12)


def test_fourier_needs_a_relay_and_conventional_refuses_one(conventional):
    with pytest.raises(ValueError, match=r"kind 'fourier' needs a relay .*got relay None\. Fix"):
        make_fourier(relay=None)
    with pytest.raises(
        ValueError, match=r"kind 'conventional' .* uses no relay lens; got relay focal_length_mm 75\. Fix"
    ):
        make_conventional(relay=RelayLensSpec(focal_length_mm=75.0))
    assert conventional.relay is None and conventional.pupil_diameter_at_mla is None


def test_lenslet_centre_outside_the_pupil_image_is_an_error(fourier):
    with pytest.raises(
        ValueError,
        match=r"pupil image at the MLA has radius 1781\.25 um.*lenslet 5 \(centre \(1800, 0\) um\) lie outside",
    ):
        evolve(fourier, "mla.lenslets.5.center_um", (1800.0, 0.0))


def test_lenslet_partly_outside_the_pupil_image_warns(fourier):
    # Relay 50 mm: pupil radius 2 x 0.95 x 50 / 40 / 2 = 1.1875 mm; the corner lenslets reach 1.2728 mm.
    with pytest.warns(
        DesignWarning,
        match=r"vignetted .*radius 1187\.5 um.*lenslet 0 \(centre \(-600, -600\) um\) reaches 1272\.79 um",
    ):
        fourier.updated(relay=RelayLensSpec(focal_length_mm=50.0, field_stop_diameter_mm=1.7))


def test_overlapping_sub_images_warn_naming_the_pairs_and_the_field_stop_that_fixes_it(fourier):
    # Field stop 3 mm: sub-images 16.8 x 3 / 75 = 0.672 mm across behind 0.6 mm lenslets: 72 um overlap.
    with pytest.warns(
        DesignWarning,
        match=r"sub-images overlap on the sensor \(each 672 um across\): lenslet 0 \(centre \(-600, -600\) um\) and lenslet 1 \(centre \(0, -600\) um\) by 72 um",
    ) as record:
        evolve(fourier, "relay.field_stop_diameter_mm", 3.0)
    assert "field_stop_diameter_mm) of at most 2.67857 mm" in str(record[0].message)


def test_unlimited_field_warns_that_overlap_cannot_be_checked(fourier):
    with pytest.warns(
        DesignWarning,
        match=r"cannot check whether sub-images overlap.*field_number_mm.*field_stop_diameter_mm",
    ):
        evolve(fourier, "relay.field_stop_diameter_mm", None)


def test_sub_image_off_the_sensor_is_an_error_and_clipped_warns(fourier):
    # 150 px x 6.5 um = 975 um sensor: lenslet centres at +-600 um lie outside it.
    with pytest.raises(
        ValueError,
        match=r"sub-images must be centred on the 975 x 975 um sensor; those of lenslet 0 \(centre \(-600, -600\) um\)",
    ):
        evolve(fourier, "camera.pixel_count", (150, 150))
    # 250 px = 1625 um: centres inside, but 600 + 297.92 um > 812.5 um: clipped.
    with pytest.warns(
        DesignWarning,
        match=r"sub-images \(595\.84 um across\) of lenslet 0 .* cut by the edge of the 1625 x 1625 um sensor",
    ):
        evolve(fourier, "camera.pixel_count", (250, 250))


def test_pixels_coarser_than_the_lenslet_nyquist_limit_warn(fourier):
    # lambda f / (2 D) = 0.68 um x 16800 um / 1200 um = 9.52 um.
    with pytest.warns(
        DesignWarning,
        match=r"camera pixel_pitch_um 10 um undersamples .*needs at most lambda f / \(2 D\) = 9\.52 um\. Fix: .*>= 17\.6471 mm",
    ):
        evolve(fourier, "camera.pixel_pitch_um", 10.0)


def test_conventional_sub_image_is_the_pupil_image(conventional):
    # radius = d tan(asin(NA / M)) = 1875 um x tan(asin(0.03)).
    assert conventional.sub_image_radius == pytest.approx(1875e-6 * math.tan(math.asin(0.03)), rel=1e-12)
    assert conventional.magnification == 10.0


def test_conventional_f_number_mismatch_warns_with_the_overlapping_lenslets(conventional):
    # d = 2.5 mm: sub-images 2 x 2500 x tan(asin(0.03)) = 150.07 um across on a 125 um pitch.
    with pytest.warns(
        DesignWarning,
        match=r"sub-images \(pupil images, 150\.068 um across\) overlap: lenslets 0 at \(-1187\.5, -1187\.5\) um and "
        r"1 at \(-1062\.5, -1187\.5\) um by 25\.0675 um.* 0 at .* and 20 at \(-1187\.5, -1062\.5\).*M / \(2 NA\) = 16\.6667",
    ):
        evolve(conventional, "mla_to_camera_distance_mm", 2.5)


def test_conventional_overlap_check_also_works_on_an_explicit_lenslet_list(conventional):
    explicit = conventional.updated(mla=conventional.mla.to_explicit())
    with pytest.warns(DesignWarning, match=r"lenslets 0 at \(-1187\.5, -1187\.5\) um and 1 at"):
        evolve(explicit, "mla_to_camera_distance_mm", 2.5)


def test_conventional_too_few_pixels_per_sub_image_warns(conventional):
    with pytest.warns(DesignWarning, match=r"only 2\.25101 camera pixels \(pixel_pitch_um 50\).*at least 3"):
        evolve(conventional, "camera.pixel_pitch_um", 50.0)


@pytest.mark.parametrize(
    ("field", "value", "pattern"),
    [
        (
            "wavelength_nm",
            0.525,
            r"wavelength_nm must be between 100 and 20000 nm; got 0\.525 nm\. Fix: .*nanometres",
        ),
        ("wavelength_nm", -525.0, r"wavelength_nm must be a finite number > 0 nm; got -525 nm\. Fix"),
        (
            "mla_to_camera_distance_mm",
            0.0,
            r"mla_to_camera_distance_mm must be a finite number > 0 mm; got 0 mm\. Fix",
        ),
        ("schema_version", 0, r"schema_version must be 1 for a Design object; got 0\. Fix: .*load_design"),
    ],
)
def test_design_field_errors(fourier, field, value, pattern):
    with pytest.raises(ValueError, match=pattern):
        fourier.updated(**{field: value})


def test_a_nested_error_keeps_its_location_and_our_message():
    bad = dict(magnification=40, numerical_aperture=1.2, immersion_index=1.0, tube_lens_focal_length_mm=200)
    with pytest.raises(
        ValueError, match=r"(?s)objective\n.*numerical_aperture 1\.2 must be below immersion_index 1 .*fix:"
    ):
        make_fourier(objective=bad)


def test_multifocal_fourier_design_validates(fourier):
    mla = MLASpec.multifocal_hex(620.0, 7, (16.8, 18.0), aperture_diameter_um=600.0)
    design = fourier.updated(mla=mla, relay=RelayLensSpec(focal_length_mm=100.0, field_stop_diameter_mm=3.6))
    assert design.mla.focal_lengths_mm == (16.8, 18.0)
    assert ObjectiveSpec.model_validate(design.objective.model_dump()) == design.objective


def test_lenslet_spec_is_reused_not_revalidated_by_updated(fourier):
    lens = LensletSpec(center_um=(0.0, 0.0), aperture_diameter_um=600.0, focal_length_mm=16.8, shape="square")
    design = fourier.updated(mla=MLASpec(lenslets=(lens,)))
    assert design.mla.lenslets[0] is lens


def _pupil_formula_agrees(message: str) -> float:
    """The radius the message states, checked against the formula it quotes (``NA f_relay / M``)."""
    found = re.search(r"radius ([\d.]+) um \(NA f_relay / M = ([\d.]+) x ([\d.]+) mm / ([\d.]+)\)", message)
    assert found, message
    radius_um, na, f_relay_mm, magnification = (float(g) for g in found.groups())
    assert radius_um == pytest.approx(na * f_relay_mm * 1e3 / magnification, rel=1e-6)
    return radius_um


def test_the_pupil_messages_quote_the_radius_formula_they_evaluate(fourier):
    # NA 0.5: radius 0.5 x 75 mm / 40 = 937.5 um (the diameter, 2 NA f_relay / M, is 1875 um); the
    # corner lenslets reach 1272.79 um, so they are vignetted, and at NA 0.3 (562.5 um) lenslet 8's
    # centre (600, 600) um, 848.5 um from the axis, lies outside.
    with pytest.warns(DesignWarning, match="vignetted") as caught:
        evolve(fourier, "objective.numerical_aperture", 0.5)
    (vignetted,) = [str(w.message) for w in caught if "vignetted" in str(w.message)]
    assert _pupil_formula_agrees(vignetted) == 937.5
    with pytest.raises(ValueError, match="lie outside") as refused:
        evolve(fourier, "objective.numerical_aperture", 0.3)
    assert _pupil_formula_agrees(str(refused.value)) == 562.5
