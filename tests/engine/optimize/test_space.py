"""Design spaces: paths, grids, units, JSON round trip, applying a point with the design's validation."""

from __future__ import annotations

import json

import pytest

from lfm_studio.engine.design.space import (
    DesignSpace,
    Parameter,
    path_parts,
    point_key,
    space_from_json,
    unit_of,
)


def test_path_parts_and_units():
    assert path_parts("mla.lenslets[3].center_um[0]") == ["mla", "lenslets", "3", "center_um", "0"]
    assert path_parts("mla.lenslets.3.center_um.0") == ["mla", "lenslets", "3", "center_um", "0"]
    assert unit_of("relay.focal_length_mm") == "mm"
    assert unit_of("mla.lenslets[3].center_um[1]") == "um"
    assert unit_of("wavelength_nm") == "nm"
    assert unit_of("objective.numerical_aperture") == ""
    with pytest.raises(ValueError, match="path"):
        path_parts("objective..numerical_aperture")


def test_grid_values_step_points_choices():
    assert Parameter("objective.numerical_aperture", 0.5, 0.7, step=0.1).grid() == (0.5, 0.6, 0.7)
    assert Parameter("x_um", 0.0, 1.0, points=5).grid() == (0.0, 0.25, 0.5, 0.75, 1.0)
    assert Parameter("mla.shape[1]", 3, 7, step=2, integer=True).grid() == (3, 5, 7)
    assert Parameter("mla.lattice", choices=("square", "hex")).grid() == ("square", "hex")
    with pytest.raises(ValueError, match="continuous"):
        Parameter("objective.numerical_aperture", 0.5, 0.7).grid()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"low": 1.0, "high": 0.5}, "low must be <= high"),
        ({"low": 0.1, "high": 0.5, "step": 0}, "step must be > 0"),
        ({"low": None, "high": 0.5}, "needs low and high"),
        ({"choices": ()}, "choices is empty"),
        ({"choices": ((1, 2),)}, "numbers, strings or booleans"),
        ({"low": 0.0, "high": 1.0, "log": True}, "log scale needs low > 0"),
    ],
)
def test_bad_parameters_are_named(kwargs, match):
    with pytest.raises(ValueError, match=match) as info:
        Parameter("objective.numerical_aperture", **kwargs)
    assert "objective.numerical_aperture" in str(info.value)


def test_json_round_trip_and_unit_check():
    space = DesignSpace(
        (
            Parameter("relay.focal_length_mm", 60.0, 90.0, step=15.0),
            Parameter("mla.lenslets[*].focal_length_mm", choices=(16.8, 20.0)),
        ),
        description="toy",
    )
    data = json.loads(space.to_json())
    assert data["parameters"][0]["unit"] == "mm"
    assert space_from_json(space.to_json()) == space
    data["parameters"][0]["unit"] = "um"
    with pytest.raises(ValueError, match=r"unit 'um'.*in 'mm'"):
        space_from_json(json.dumps(data))
    with pytest.raises(ValueError, match="not valid JSON"):
        space_from_json("{")
    with pytest.raises(ValueError, match="unknown key"):
        space_from_json('{"parameters": [{"path": "wavelength_nm", "low": 1, "high": 2, "stp": 1}]}')


def test_grid_order_and_size():
    space = DesignSpace((Parameter("a_um", 0, 1, step=1), Parameter("b", choices=("x", "y", "z"))))
    points = list(space.grid())
    assert space.grid_size() == len(points) == 6
    assert points[:2] == [{"a_um": 0.0, "b": "x"}, {"a_um": 0.0, "b": "y"}]  # last varies fastest
    assert len({point_key(p) for p in points}) == 6
    assert point_key({"b": "x", "a_um": 0.1 + 0.2}) == point_key({"a_um": 0.3, "b": "x"})


def test_apply_writes_values_and_validates(flfm):
    space = DesignSpace(
        (
            Parameter("objective.numerical_aperture", 0.8, 0.9, step=0.1),
            Parameter("mla.lenslets[4].center_um[0]", -10, 10, step=10),
            Parameter("mla.lenslets[*].focal_length_mm", choices=(16.8, 20.0)),
        )
    )
    space.check_paths(flfm)
    assert space.values_of(flfm) == {
        "objective.numerical_aperture": 0.95,
        "mla.lenslets[4].center_um[0]": 0.0,
        "mla.lenslets[*].focal_length_mm": 16.8,
    }
    out = space.apply(
        flfm,
        {
            "objective.numerical_aperture": 0.8,
            "mla.lenslets[4].center_um[0]": 0.0,
            "mla.lenslets[*].focal_length_mm": 20.0,
        },
    )
    assert out.objective.numerical_aperture == 0.8
    assert {lens.focal_length_mm for lens in out.mla.lenslets} == {20.0}
    group = DesignSpace((Parameter("mla.lenslets[1,3].focal_length_mm", choices=(20.0,)),))
    tied = group.apply(flfm, {"mla.lenslets[1,3].focal_length_mm": 20.0})
    assert [lens.focal_length_mm for lens in tied.mla.lenslets] == [16.8, 20.0, 16.8, 20.0, *[16.8] * 5]
    assert flfm.objective.numerical_aperture == 0.95  # the base is untouched
    with pytest.raises(ValueError, match="must not overlap"):  # lenslet 4 pushed into lenslet 3
        space.apply(flfm, {"mla.lenslets[4].center_um[0]": -10.0})
    with pytest.raises(ValueError, match="numerical_aperture"):
        space.apply(flfm, {"objective.numerical_aperture": 1.2})  # air objective: NA < 1


def test_unknown_paths_are_named(flfm):
    with pytest.raises(ValueError, match=r"'pitch_um'.*known"):
        DesignSpace((Parameter("mla.pitch_um", 100, 200, step=50),)).check_paths(flfm)
    with pytest.raises(ValueError, match="not an index"):
        DesignSpace((Parameter("mla.lenslets[40].center_um[0]", 0, 1, step=1),)).check_paths(flfm)
    with pytest.raises(ValueError, match="not in the design space"):
        DesignSpace((Parameter("wavelength_nm", 500, 600, step=50),)).apply(
            flfm, {"relay.focal_length_mm": 1.0}
        )


def test_a_zernike_coefficient_of_the_pupil_phase_is_a_parameter(flfm):
    """``pupil_phase.zernike_waves.4`` (or ``[4]``) frees the defocus coefficient of a Fourier design's
    pupil phase mask, in waves; a term the design does not list reads as 0 and is created when written."""
    masked = flfm.updated(pupil_phase={"zernike_waves": {"4": 0.0, "11": 0.02}})
    entry = {"path": "pupil_phase.zernike_waves.4", "low": -0.2, "high": 0.2, "points": 5, "unit": "waves"}
    space = space_from_json(json.dumps({"parameters": [entry]}))
    param = space.parameters[0]
    assert param.unit == "waves" and unit_of("pupil_phase.zernike_waves[4]") == "waves"
    assert param.grid() == (-0.2, -0.1, 0.0, 0.1, 0.2)
    space.check_paths(masked)
    assert space.values_of(masked) == {"pupil_phase.zernike_waves.4": 0.0}
    out = space.apply(masked, {"pupil_phase.zernike_waves.4": -0.1})
    assert out.pupil_phase.zernike_waves == {4: -0.1, 11: 0.02}
    assert masked.pupil_phase.zernike_waves == {4: 0.0, 11: 0.02}  # the base is untouched
    space.check_paths(flfm)  # no mask in the design: the term starts at 0 waves
    assert space.values_of(flfm) == {"pupil_phase.zernike_waves.4": 0.0}
    assert space.apply(flfm, {"pupil_phase.zernike_waves.4": 0.1}).pupil_phase.zernike_waves == {4: 0.1}
    assert flfm.pupil_phase is None  # the base is untouched
    seventh = DesignSpace((Parameter("pupil_phase.zernike_waves[7]", -0.1, 0.1, points=3),))
    assert seventh.values_of(masked) == {"pupil_phase.zernike_waves[7]": 0.0}
    assert seventh.apply(masked, {"pupil_phase.zernike_waves[7]": 0.05}).pupil_phase.zernike_waves == {
        4: 0.0,
        7: 0.05,
        11: 0.02,
    }
    with pytest.raises(ValueError, match=r"no field 'x' here"):
        DesignSpace((Parameter("pupil_phase.zernike_waves.x", -0.1, 0.1, points=3),)).check_paths(masked)
