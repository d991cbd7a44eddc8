"""Part specs: validators name the parameter, its value (with unit) and a fix; SI accessors convert once."""

from __future__ import annotations

import math

import pytest
from pydantic import ValidationError

from lfm_studio.engine import units
from lfm_studio.engine.design import (
    AccuracySpec,
    CameraSpec,
    DepthSpec,
    DesignError,
    LensletSpec,
    ObjectiveSpec,
    RelayLensSpec,
)


def objective(**changes):
    fields = dict(
        magnification=20.0, numerical_aperture=0.5, immersion_index=1.333, tube_lens_focal_length_mm=180.0
    )
    return ObjectiveSpec(**{**fields, **changes})


def test_specs_are_frozen_and_forbid_unknown_fields():
    spec = objective()
    with pytest.raises(ValidationError, match="frozen"):
        spec.numerical_aperture = 0.8
    with pytest.raises(ValidationError, match=r"numerical_apertur\n  Extra inputs are not permitted"):
        objective(numerical_apertur=0.8)


def test_na_must_be_below_immersion_index_and_message_names_both_and_a_fix():
    with pytest.raises(
        ValueError, match=r"numerical_aperture 1\.4 must be below immersion_index 1\.33.*fix: "
    ):
        objective(numerical_aperture=1.4, immersion_index=1.33)
    with pytest.raises(ValueError, match=r"numerical_aperture 1 must be below immersion_index 1\b"):
        objective(numerical_aperture=1.0, immersion_index=1.0)  # NA = n is a 90 degree cone: impossible


@pytest.mark.parametrize(
    ("changes", "pattern"),
    [
        ({"magnification": 0.0}, r"magnification must be a finite number > 0; got 0\. Fix"),
        ({"numerical_aperture": -0.1}, r"numerical_aperture must be a finite number > 0; got -0\.1\. Fix"),
        (
            {"tube_lens_focal_length_mm": math.nan},
            r"tube_lens_focal_length_mm must be .* > 0 mm; got nan mm\. Fix",
        ),
        ({"immersion_index": 0.9}, r"immersion_index must be >= 1 \(vacuum\); got 0\.9\. Fix"),
        ({"field_number_mm": -22.0}, r"field_number_mm must be .* > 0 mm; got -22 mm\. Fix"),
        ({"magnification": 0.4}, r"image-side NA.*must be below 1; got 0\.5 / 0\.4\. Fix"),
    ],
)
def test_objective_errors_name_parameter_value_unit_and_fix(changes, pattern):
    with pytest.raises(ValueError, match=pattern):
        objective(**changes)


def test_objective_si_accessors_and_pupil_geometry():
    spec = objective(field_number_mm=26.5)
    # Exact float64 arithmetic of one or two operations: relative tolerance 1e-12 (round-off only).
    assert spec.tube_lens_focal_length == pytest.approx(0.180, rel=1e-12)
    assert spec.focal_length == pytest.approx(9e-3, rel=1e-12)  # f_obj = f_tube / M
    assert spec.back_pupil_diameter == pytest.approx(2 * 0.5 * 9e-3, rel=1e-12)  # 2 NA f_obj
    assert spec.half_angle == pytest.approx(math.asin(0.5 / 1.333), rel=1e-12)
    assert spec.field_of_view_diameter == pytest.approx(26.5e-3 / 20, rel=1e-12)
    assert objective().field_of_view_diameter is None


def test_relay_lens():
    relay = RelayLensSpec(focal_length_mm=75.0, field_stop_diameter_mm=2.66)
    assert relay.focal_length == pytest.approx(75 * units.mm, rel=1e-12)
    assert relay.field_stop_diameter == pytest.approx(2.66e-3, rel=1e-12)
    with pytest.raises(ValueError, match=r"focal_length_mm must be a finite number > 0 mm; got -75 mm\. Fix"):
        RelayLensSpec(focal_length_mm=-75.0)
    with pytest.raises(ValueError, match=r"field_stop_diameter_mm must be .* > 0 mm; got 0 mm"):
        RelayLensSpec(focal_length_mm=75.0, field_stop_diameter_mm=0.0)


@pytest.mark.parametrize(
    ("changes", "pattern"),
    [
        ({"pixel_pitch_um": 0.0}, r"pixel_pitch_um must be a finite number > 0 um; got 0 um\. Fix"),
        ({"pixel_count": (0, 2048)}, r"pixel_count must be \(ny, nx\) with both >= 1; got \(0, 2048\)\. Fix"),
        (
            {"quantum_efficiency": 82.0},
            r"quantum_efficiency must be in \(0, 1\]; got 82\. Fix: give a fraction",
        ),
        ({"read_noise_e": -1.0}, r"read_noise_e must be >= 0 e- rms; got -1 e-\. Fix"),
        ({"bit_depth": 40}, r"bit_depth must be 1-32 bits; got 40\. Fix"),
        (
            {"bit_depth": 8, "baseline_adu": 300.0},
            r"baseline_adu must be in \[0, 256\) ADU .* got 300 ADU\. Fix",
        ),
        ({"gain_adu_per_e": 0.0}, r"gain_adu_per_e must be .* > 0 ADU/e-; got 0 ADU/e-\. Fix"),
        ({"full_well_e": -5.0}, r"full_well_e must be .* > 0 e-; got -5 e-\. Fix"),
    ],
)
def test_camera_errors_name_parameter_value_unit_and_fix(changes, pattern):
    with pytest.raises(ValueError, match=pattern):
        CameraSpec(**{"pixel_pitch_um": 6.5, "pixel_count": (2048, 2048), **changes})


def test_camera_geometry():
    camera = CameraSpec(pixel_pitch_um=6.5, pixel_count=(1000, 2048))
    assert camera.pixel_pitch == pytest.approx(6.5e-6, rel=1e-12)
    width, height = camera.sensor_size
    assert (width, height) == (
        pytest.approx(2048 * 6.5e-6, rel=1e-12),
        pytest.approx(1000 * 6.5e-6, rel=1e-12),
    )


def test_lenslet_validation_and_accessors():
    lens = LensletSpec(center_um=(150.0, -75.0), aperture_diameter_um=150.0, focal_length_mm=3.0)
    assert lens.center == (pytest.approx(150e-6, rel=1e-12), pytest.approx(-75e-6, rel=1e-12))
    assert lens.numerical_aperture == pytest.approx(150e-6 / 6e-3, rel=1e-12)  # paraxial D / (2 f)
    with pytest.raises(ValueError, match=r"aperture_diameter_um must be .* > 0 um; got -150 um"):
        LensletSpec(center_um=(0.0, 0.0), aperture_diameter_um=-150.0, focal_length_mm=3.0)
    with pytest.raises(
        ValueError, match=r"focal_length_mm must be .* > 0 mm; got 0 mm\. Fix: give a converging"
    ):
        LensletSpec(center_um=(0.0, 0.0), aperture_diameter_um=150.0, focal_length_mm=0.0)
    with pytest.raises(ValueError, match=r"center_um x must be finite; got inf um"):
        LensletSpec(center_um=(math.inf, 0.0), aperture_diameter_um=150.0, focal_length_mm=3.0)
    with pytest.raises(ValidationError, match="shape"):
        LensletSpec(center_um=(0.0, 0.0), aperture_diameter_um=150.0, focal_length_mm=3.0, shape="hexagon")


def test_depths():
    depths = DepthSpec(depth_range_um=(-10.0, 10.0), depth_step_um=2.5)
    assert depths.count == 9
    assert depths.values_um == (-10.0, -7.5, -5.0, -2.5, 0.0, 2.5, 5.0, 7.5, 10.0)
    assert depths.values[-1] == pytest.approx(10e-6, rel=1e-12)
    assert DepthSpec(depth_range_um=(3.0, 3.0), depth_step_um=1.0).values_um == (3.0,)
    # 0.1 is not exact in binary: 0 -> 0.3 in steps of 0.1 must still include the end point.
    assert DepthSpec(depth_range_um=(0.0, 0.3), depth_step_um=0.1).count == 4
    assert DepthSpec(depth_range_um=(0.0, 1.0), depth_step_um=0.3).values_um[-1] == pytest.approx(
        0.9, rel=1e-12
    )


@pytest.mark.parametrize(
    ("rng", "step", "pattern"),
    [
        (
            (10.0, -10.0),
            1.0,
            r"depth_range_um must be ordered \(start <= stop\); got \(10, -10\) um\. Fix: write \(-10, 10\)",
        ),
        ((-10.0, 10.0), 0.0, r"depth_step_um must be a finite number > 0 um; got 0 um\. Fix"),
        ((-10.0, 10.0), -1.0, r"depth_step_um must be a finite number > 0 um; got -1 um"),
        ((-100.0, 100.0), 0.001, r"gives 200001 depths, more than 4096\. Fix: use a larger step"),
        ((math.nan, 10.0), 1.0, r"depth_range_um start must be finite; got nan um"),
    ],
)
def test_depth_errors(rng, step, pattern):
    with pytest.raises(ValueError, match=pattern):
        DepthSpec(depth_range_um=rng, depth_step_um=step)


def test_accuracy_presets_fill_knobs_and_edits_are_kept():
    assert AccuracySpec().preset == "standard"
    reference = AccuracySpec.from_preset("reference")
    assert (reference.dtype, reference.propagator, reference.per_lenslet) == (
        "float64",
        "bandlimited_asm",
        True,
    )
    assert reference.matches_preset()
    edited = AccuracySpec(preset="preview", dtype="float64")  # a knob given explicitly wins over the preset
    assert edited.dtype == "float64" and edited.oversampling == 1 and not edited.matches_preset()
    with pytest.raises(ValueError, match=r"accuracy preset must be one of .*got 'fast'"):
        AccuracySpec(preset="fast")
    with pytest.raises(ValidationError, match="propagator"):
        AccuracySpec(propagator="rayleigh_sommerfeld")
    with pytest.raises(ValueError, match=r"oversampling must be an integer >= 1; got 0"):
        AccuracySpec(oversampling=0)
    with pytest.raises(ValueError, match=r"padding must be in \[1, 16\]; got 0\.5"):
        AccuracySpec(padding=0.5)
    with pytest.raises(ValidationError, match="Field required"):
        AccuracySpec(preset="custom", dtype="float32")  # custom sets take no defaults


def test_design_error_is_a_value_error():
    assert issubclass(DesignError, ValueError)
