"""Changing a design builds a new, fully validated design; the original is untouched."""

from __future__ import annotations

import pytest

from lfm_studio.engine.design import Design, DesignWarning, ObjectiveSpec, evolve


def test_updated_returns_a_new_validated_design(fourier):
    changed = fourier.updated(wavelength_nm=520.0)
    assert changed.wavelength_nm == 520.0 and fourier.wavelength_nm == 680.0
    assert changed.wavelength == pytest.approx(520e-9, rel=1e-12)
    with pytest.raises(ValueError, match=r"numerical_aperture 1\.1 must be below immersion_index 1"):
        fourier.updated(objective=fourier.objective.model_dump() | {"numerical_aperture": 1.1})
    with pytest.raises(ValueError, match=r"Design has no field\(s\) \['wavelength'\]"):
        fourier.updated(wavelength=5e-7)


def test_updated_runs_the_design_level_checks(fourier):
    with pytest.raises(ValueError, match=r"kind 'conventional' .* uses no relay lens"):
        fourier.updated(kind="conventional")


def test_model_copy_would_skip_validation_evolve_does_not(fourier):
    # The pitfall evolve exists for: pydantic's model_copy(update=...) accepts an impossible objective.
    broken = fourier.objective.model_copy(update={"numerical_aperture": 1.5})
    assert broken.numerical_aperture == 1.5
    with pytest.raises(ValueError, match=r"numerical_aperture 1\.5 must be below immersion_index 1"):
        evolve(fourier, "objective.numerical_aperture", 1.5)


def test_evolve_paths_into_nested_specs_and_tuples(fourier):
    d = evolve(fourier, "objective.numerical_aperture", 0.8)
    assert isinstance(d, Design) and d.objective.numerical_aperture == 0.8
    d = evolve(fourier, "mla.lenslets.8.focal_length_mm", 20.0)
    assert d.mla.lenslets[8].focal_length_mm == 20.0 and d.mla.lenslets[7] is fourier.mla.lenslets[7]
    d = evolve(fourier, ("camera", "pixel_count", 1), 600)
    assert d.camera.pixel_count == (512, 600)
    spec = evolve(fourier.objective, "magnification", 20.0)
    assert isinstance(spec, ObjectiveSpec) and spec.focal_length == pytest.approx(10e-3, rel=1e-12)


@pytest.mark.parametrize(
    ("path", "pattern"),
    [
        ("objective.na", r"objective has no field 'na'; known: \['magnification', 'numerical_aperture'"),
        ("mla.lenslets.9.focal_length_mm", r"mla\.lenslets has 9 items; '9' is not a valid index"),
        ("wavelength_nm.x", r"cannot go into wavelength_nm \(a float\) with 'x'"),
        ("", r"path must name a field"),
    ],
)
def test_evolve_bad_paths(fourier, path, pattern):
    with pytest.raises(ValueError, match=pattern):
        evolve(fourier, path, 1.0)


def test_evolve_on_a_regular_grid_explains_how_to_edit_one_lenslet(conventional):
    with pytest.raises(
        ValueError, match=r"no field 'lenslets' \(a RegularMLASpec: edit pitch_um/shape, or convert it"
    ):
        evolve(conventional, "mla.lenslets.0.focal_length_mm", 2.0)
    assert evolve(conventional, "mla.pitch_um", 130.0).mla.pitch_um == 130.0


def test_evolve_warns_like_construction(fourier):
    with pytest.warns(DesignWarning, match="undersamples"):
        evolve(fourier, "camera.pixel_pitch_um", 12.0)
