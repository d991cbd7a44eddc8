"""The studio's design messages name parameters by the labels of the parameter panel's fields.

The engine's checks name a value by its key (``numerical_aperture``), which the CLI and design
files keep; where the studio shows a refusal or a design warning, the key reads as the label the
user sees beside the field (``Numerical aperture``).
"""

from __future__ import annotations

import pytest

from lfm_studio.engine.design import load_design, load_preset, save_design
from lfm_studio.ui.edits import try_changes, with_design_warnings
from lfm_studio.ui.field_specs import FIELDS, LABELS, in_field_labels


def test_every_panel_field_has_its_label_by_path():
    assert {spec.path: spec.label for spec in FIELDS}.items() <= LABELS.items()


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (
            "numerical_aperture 1.2 must be below immersion_index 1 (NA = n sin(alpha) < n)",
            "Numerical aperture 1.2 must be below immersion index 1 (NA = n sin(alpha) < n)",
        ),
        (
            "quantum_efficiency must be in (0, 1]; got 1.5. Fix: e.g. 0.8; depth_step_um must be > 0",
            "Quantum efficiency must be in (0, 1]; got 1.5. Fix: e.g. 0.8; Depth step must be > 0",
        ),
        ("Fix: shorten mla_to_camera_distance_mm.", "Fix: shorten MLA to camera distance."),  # acronym kept
        ("relay.focal_length_mm: too short", "Fourier lens focal length: too short"),  # a path
    ],
)
def test_keys_read_as_field_labels(text, expected):
    assert in_field_labels(text) == expected


def test_words_and_keys_no_field_shows_are_left_alone():
    # A lenslet's focal_length_mm is not the relay's field; "number" and "maximum" are words.
    text = "lenslet 3 focal_length_mm 5 is the maximum number; lenslets.0.center_um bad"
    assert in_field_labels(text) == text


def test_an_edit_refused_by_a_design_check_names_the_fields_by_their_labels():
    design = load_preset("flfm_guo2019")
    outcome = try_changes(design, {"objective.numerical_aperture": 2.5})
    assert not outcome.ok
    assert "Numerical aperture 2.5 must be below immersion index" in outcome.error
    assert "numerical_aperture" not in outcome.error and "immersion_index" not in outcome.error


def test_design_warnings_name_the_fields_by_their_labels(tmp_path):
    design = load_preset("flfm_guo2019")
    outcome = try_changes(design, {"mla_to_camera_distance_mm": design.mla_to_camera_distance_mm * 3})
    overlap = [w for w in outcome.warnings if "overlap" in w]
    assert outcome.ok and overlap, outcome.warnings
    assert "MLA to camera distance" in overlap[0] and "mla_to_camera_distance_mm" not in overlap[0]
    path = save_design(outcome.design, tmp_path / "overlapping.json")
    _, opened = with_design_warnings(load_design, path)  # what File > Open shows
    assert opened == outcome.warnings
