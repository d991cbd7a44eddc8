"""error_text: a refused design or spec shows our message, not pydantic's wrapping, wherever errors
become text (CLI, napari notifications, the studio's status line)."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from lfm_studio.engine.design import evolve, load_preset
from lfm_studio.engine.errors import error_text

BOILERPLATE = ("validation error for", "[type=", "input_value", "errors.pydantic.dev", "Value error, ")


def test_our_value_error_is_shown_alone():
    with pytest.raises(ValidationError) as refused:
        evolve(load_preset("flfm_guo2019"), "objective.numerical_aperture", -0.5)
    assert all(part in str(refused.value) for part in ("validation error for", "errors.pydantic.dev"))
    assert (
        error_text(refused.value)
        == "numerical_aperture must be a finite number > 0; got -0.5. Fix: e.g. 0.5."
    )


def test_a_pydantic_type_error_keeps_its_place_and_value():
    design = load_preset("flfm_guo2019")
    with pytest.raises(ValidationError) as refused:
        design.updated(wavelength_nm="green")
    text = error_text(refused.value)
    assert text.startswith("wavelength_nm: ") and "(got 'green')" in text
    assert not any(part in text for part in BOILERPLATE), text


def test_other_errors_are_their_own_text():
    assert (
        error_text(ValueError("x must be > 0; got -1. Fix: e.g. 1.")) == "x must be > 0; got -1. Fix: e.g. 1."
    )
    assert error_text(FileNotFoundError("no such file: a.json")) == "no such file: a.json"
