"""The report: requirement checks per preset, unit-suffixed JSON and its round trip."""

from __future__ import annotations

import json
import math

import pytest

from lfm_studio.engine.design import evolve, list_presets, load_preset
from lfm_studio.engine.performance import DesignMetrics, compute_design_metrics, format_metrics_table


def assert_close(a, b, path="root"):
    """Recursive equality with rel 1e-12 on floats (unit conversions round in the last bits)."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            assert_close(a[key], b[key], f"{path}.{key}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            assert_close(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and not isinstance(b, bool):
        assert b == pytest.approx(a, rel=1e-12), path
    else:
        assert a == b, path


@pytest.mark.parametrize("name", list_presets())
def test_every_preset_reports_closed_forms_and_four_requirement_checks(name):
    m = compute_design_metrics(load_preset(name))
    assert m.measured is None
    assert [c.quantity for c in m.requirements] == [
        "field_of_view", "depth_of_field", "lateral_resolution", "axial_resolution"
    ]  # fmt: skip
    assert all(c.basis == "closed_form" for c in m.requirements)
    # None of the bundled designs meets all four (thesis 2.4: no published LFM does).
    assert m.requirements_met is False


def test_guo_flfm_passes_lateral_resolution_and_fails_the_field_of_view():
    checks = {c.quantity: c for c in compute_design_metrics(load_preset("flfm_guo2019")).requirements}
    # Rayleigh 0.61 lambda / NA_eff = 0.61 x 0.68 um / 0.16 = 2.5925 um <= 3 um
    assert checks["lateral_resolution"].passed is True
    assert checks["lateral_resolution"].margin == pytest.approx(3e-6 - 0.61 * 0.68e-6 / 0.16)
    assert checks["lateral_resolution"].criterion == "Rayleigh 0.61 lambda/NA"
    assert checks["field_of_view"].passed is False  # 66.5 um << 800 um
    assert checks["axial_resolution"].passed is False  # 5.73 um > 5 um
    assert checks["depth_of_field"].passed is False  # 31 um < 200 um


def test_xlfm_passes_the_depth_of_field_with_its_two_focal_groups():
    checks = {c.quantity: c for c in compute_design_metrics(load_preset("xlfm_cong2017")).requirements}
    assert checks["depth_of_field"].passed is True  # 440 um >= 200 um
    assert checks["field_of_view"].passed is False  # the assumed 645 um field stop < 800 um


def test_json_has_units_in_key_names_and_values_in_those_units():
    d = json.loads(compute_design_metrics(load_preset("flfm_guo2019")).to_json())
    assert d["schema"] == "lfm_studio.design_metrics" and d["schema_version"] == 2
    assert d["wavelength_nm"] == pytest.approx(680.0)
    cf = d["closed_form"]
    assert cf["lateral_resolution_um"] == pytest.approx(0.61 * 0.68 / 0.16)
    assert cf["lateral_criterion"] == "rayleigh"
    lateral = next(c for c in d["requirements"] if c["quantity"] == "lateral_resolution")
    assert lateral["criterion"] == "Rayleigh 0.61 lambda/NA"
    assert cf["field_of_view_um"] == pytest.approx(66.5)
    assert cf["depth_range_um"] == pytest.approx([-15.5483, 15.5483], rel=1e-5)
    assert cf["magnification"] == pytest.approx(8.96) and cf["number_of_views"] == 9
    assert not any(key.endswith("_m") for key in cf)  # no SI metres leak into the file
    check = d["requirements"][0]
    assert check["limit_um"] == pytest.approx(800.0) and check["value_um"] == pytest.approx(66.5)
    assert check["passed"] is False and check["relative_margin"] == pytest.approx(-0.916875)
    assert d["measured"] is None and d["requirements_met"] is False


@pytest.mark.parametrize("name", ["xlfm_cong2017", "lfm_10x_na03"])
def test_json_round_trip(name):
    m = compute_design_metrics(load_preset(name))
    back = DesignMetrics.from_json(m.to_json())
    assert_close(m.to_dict(), back.to_dict())
    assert back.closed_form.lateral_resolution == pytest.approx(m.closed_form.lateral_resolution, rel=1e-12)
    assert back.closed_form.notes == m.closed_form.notes and isinstance(back.closed_form.depth_range, tuple)
    assert back.requirements[0].passed == m.requirements[0].passed


def test_json_round_trip_with_measurements(guo_metrics):
    m = guo_metrics
    back = DesignMetrics.from_json(m.to_json())
    assert_close(m.to_dict(), back.to_dict())
    assert back.measured.axial_two_point == pytest.approx(m.measured.axial_two_point, rel=1e-12)
    assert len(back.requirements) == 7


def test_undefined_values_serialise_as_null_not_nan():
    from lfm_studio.engine.design import MLASpec

    lens = {
        "center_um": (0.0, 0.0),
        "aperture_diameter_um": 600.0,
        "focal_length_mm": 16.8,
        "shape": "square",
    }
    design = load_preset("flfm_guo2019").updated(mla=MLASpec(lenslets=(lens,)))
    m = compute_design_metrics(design)
    d = json.loads(m.to_json())
    assert d["closed_form"]["axial_resolution_um"] is None
    axial = next(c for c in d["requirements"] if c["quantity"] == "axial_resolution")
    assert axial["passed"] is None and axial["value_um"] is None
    assert m.requirements_met is False  # the field of view still fails
    assert not math.isnan(d["closed_form"]["lateral_resolution_um"])


def test_other_schemas_are_refused():
    with pytest.raises(ValueError, match="schema"):
        DesignMetrics.from_dict({"schema": "something else", "schema_version": 1})


def test_table_names_each_row_by_its_json_key():
    m = compute_design_metrics(load_preset("lfm_prevedel2014"))
    table = format_metrics_table(m)
    for key in m.to_dict()["closed_form"]:
        if key != "notes":
            assert key in table
    assert "field_of_view >= 800 um" in table and "FAIL" in table


def test_criterion_can_flip_a_requirement_and_is_named_in_json_and_table():
    # XLFM: NA_eff = 1/16 at 525 nm: Abbe 4.2 um, Rayleigh 5.124 um, Sparrow 3.948 um; a 4.5 um
    # requirement passes by Abbe and Sparrow but fails by Rayleigh (the 1.22x of issue 22).
    from lfm_studio.engine.performance import Requirement

    requirement = (Requirement("lateral_resolution", "<=", 4.5e-6, "test"),)
    outcomes = {}
    for criterion, factor in (("rayleigh", 0.61), ("abbe", 0.5), ("sparrow", 0.47)):
        m = compute_design_metrics(
            load_preset("xlfm_cong2017"), requirements=requirement, criterion=criterion
        )
        (check,) = m.requirements
        assert check.value == pytest.approx(factor * 525e-9 * 16, rel=1e-9)
        outcomes[criterion] = check.passed
        back = DesignMetrics.from_json(m.to_json())
        assert (
            back.closed_form.lateral_criterion == criterion
            and back.requirements[0].criterion == check.criterion
        )
        assert f"lateral_resolution ({check.criterion}) <= 4.5 um" in format_metrics_table(m)
    assert outcomes == {"rayleigh": False, "abbe": True, "sparrow": True}


def test_version_1_records_load_as_abbe():
    d = json.loads(compute_design_metrics(load_preset("flfm_guo2019"), criterion="abbe").to_json())
    d["schema_version"] = 1
    del d["closed_form"]["lateral_criterion"]
    for check in d["requirements"]:
        del check["criterion"]
    back = DesignMetrics.from_dict(d)
    assert back.closed_form.lateral_criterion == "abbe" and back.requirements[0].criterion == ""


@pytest.mark.parametrize("criterion", ["rayleigh", "abbe", "sparrow"])
def test_a_sampling_limited_lateral_resolution_is_labelled_by_its_sampling_limit(criterion):
    # Prevedel 20x/0.5, 150 um lenslets, 525 nm: pitch / M = 7.5 um >> 0.61 x 0.525 um / 0.5 = 0.64 um,
    # so the value is the lenslet sampling, whatever the criterion (walk-through 6: labelled Rayleigh).
    m = compute_design_metrics(load_preset("lfm_prevedel2014"), criterion=criterion)
    lateral = next(c for c in m.requirements if c.quantity == "lateral_resolution")
    assert lateral.value == pytest.approx(150e-6 / 20) and lateral.value > 0.61 * 0.525e-6 / 0.5
    assert lateral.criterion == "lenslet sampling pitch/M, same for every criterion"
    assert m.closed_form.lateral_resolution_limit == lateral.criterion
    assert DesignMetrics.from_json(m.to_json()).requirements[2].criterion == lateral.criterion


@pytest.mark.filterwarnings("ignore::lfm_studio.engine.design.DesignWarning")  # 13 um pixels undersample
def test_a_pixel_limited_fourier_lateral_resolution_is_labelled_by_the_pixels():
    # Guo FLFM with 13 um pixels: 2 x 13 um / (40 x 16.8 / 75) = 2.90 um > Rayleigh 0.61 x 0.68 um / 0.16 = 2.59 um.
    design = evolve(load_preset("flfm_guo2019"), "camera.pixel_pitch_um", 13.0)
    lateral = compute_design_metrics(design).requirements[2]
    assert (
        lateral.value == pytest.approx(2 * 13e-6 / (40 * 16.8 / 75)) and lateral.value > 0.61 * 0.68e-6 / 0.16
    )
    assert lateral.criterion == "Nyquist 2 pixels/M_T, same for every criterion"
