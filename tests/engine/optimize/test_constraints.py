"""Manufacturability constraints: each infeasible design gets its named reason, never a crash."""

from __future__ import annotations

import pytest

from lfm_studio.engine.optimize import (
    DesignSpace,
    Evaluator,
    FocalLengthCatalogue,
    InsidePupil,
    MinimumLensletSize,
    NoSubImageOverlap,
    Parameter,
    SubImagesOnSensor,
    grid_search,
    objective_named,
)
from lfm_studio.engine.optimize.constraints import infeasible_from_error

from .conftest import small


def test_catalogue_snaps_to_the_nearest_stock_focal_length(flfm):
    snapped = FocalLengthCatalogue((15.0, 18.0, 30.0)).snap(flfm)  # 16.8 mm: 18 is 1.2 away, 15 is 1.8
    assert {lens.focal_length_mm for lens in snapped.mla.lenslets} == {18.0}
    regular = small("lfm_10x_na03", 130, (-20.0, 20.0), 20.0)
    assert regular.mla.layout == "regular"
    f = regular.mla.focal_length_mm
    assert FocalLengthCatalogue((f + 0.4, f - 0.3)).snap(regular).mla.focal_length_mm == pytest.approx(
        f - 0.3
    )
    with pytest.raises(ValueError, match="focal_lengths_mm"):
        FocalLengthCatalogue((10.0, -1.0))


def test_minimum_lenslet_size(flfm):
    assert MinimumLensletSize(600.0).check(flfm) is None
    found = MinimumLensletSize(700.0).check(flfm)
    assert found.reason == "lenslet_too_small"
    assert "600 um" in found.message and "700 um" in found.message


def test_inside_pupil_refuses_vignetted_lenslets(flfm):
    # Pupil image radius NA f_relay / M: 0.7 x 75 / 40 = 1.3125 mm holds the corner squares (reach
    # sqrt(2) x 900 um = 1.273 mm); 0.65 gives 1.219 mm, which clips them (the design only warns).
    assert (
        InsidePupil().check(
            flfm.updated(objective={**flfm.objective.model_dump(), "numerical_aperture": 0.7})
        )
        is None
    )
    with pytest.warns(UserWarning, match="vignetted"):
        clipped = flfm.updated(objective={**flfm.objective.model_dump(), "numerical_aperture": 0.65})
    found = InsidePupil().check(clipped)
    assert found.reason == "outside_pupil" and "1218.75 um" in found.message


def test_sub_images_overlap_and_leave_the_sensor(flfm):
    # Sub-image diameter = field stop x d / f_relay: 2.66 x 16.8 / 75 = 596 um < the 600 um pitch.
    assert NoSubImageOverlap().check(flfm) is None
    with pytest.warns(UserWarning, match="overlap"):
        wide = flfm.updated(relay={**flfm.relay.model_dump(), "field_stop_diameter_mm": 3.0})  # 672 um
    found = NoSubImageOverlap().check(wide)
    assert found.reason == "sub_image_overlap" and "lenslets 0 and 1 by 72 um" in found.message
    assert SubImagesOnSensor().check(flfm) is None
    with pytest.warns(UserWarning, match="cut by the edge"):
        cropped = flfm.updated(camera={**flfm.camera.model_dump(), "pixel_count": (256, 256)})
    found = SubImagesOnSensor().check(cropped)  # 600 + 298 um > 832 um half-width
    assert found.reason == "sub_image_off_sensor" and "lenslet 0" in found.message


def test_design_refusals_get_reasons(flfm):
    space = DesignSpace((Parameter("mla.lenslets[4].center_um[0]", -20, 20, step=20),))
    with pytest.raises(ValueError) as info:
        space.apply(flfm, {"mla.lenslets[4].center_um[0]": 20.0})
    found = infeasible_from_error(info.value)
    assert found.reason == "lenslet_overlap"
    assert found.message.startswith("mla.lenslets: lenslet apertures must not overlap")
    assert "errors.pydantic.dev" not in found.message


def test_grid_search_records_infeasible_points_with_reasons(flfm):
    space = DesignSpace(
        (
            Parameter("mla.lenslets[4].center_um[0]", -20, 20, step=20),
            Parameter("relay.field_stop_diameter_mm", choices=(2.66, 3.0)),
        )
    )
    evaluator = Evaluator(flfm, space, [objective_named("lateral_resolution")])
    result = grid_search(evaluator)
    reasons = {
        tuple(r.params.values()): (r.infeasible.reason if r.infeasible else None) for r in result.records
    }
    assert reasons == {
        (-20.0, 2.66): "lenslet_overlap",
        (-20.0, 3.0): "lenslet_overlap",
        (0.0, 2.66): None,
        (0.0, 3.0): "sub_image_overlap",
        (20.0, 2.66): "lenslet_overlap",
        (20.0, 3.0): "lenslet_overlap",
    }
    for record in result.infeasible:
        assert record.values is None and record.design_json is None and record.infeasible.message
    assert evaluator.evaluations == 1
    assert result.best.params == {"mla.lenslets[4].center_um[0]": 0.0, "relay.field_stop_diameter_mm": 2.66}
