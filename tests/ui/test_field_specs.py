"""The studio's design messages name parameters by the labels of the parameter panel's fields.

The engine's checks name a value by its key (``numerical_aperture``) and write micrometres as
"um", which the CLI and design files keep; where the studio shows a refusal or a design warning,
the key reads as the label the user sees beside the field (``Numerical aperture``) and the unit
as "µm", as the studio writes it everywhere else.
"""

from __future__ import annotations

import pytest

from lfm_studio.engine.design import load_design, load_preset, save_design
from lfm_studio.ui.edits import try_changes, with_design_warnings
from lfm_studio.ui.field_specs import FIELDS, LABELS, in_field_labels
from lfm_studio.widgets.numeric_text import shown_units_in


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


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("got 0 um.", "got 0 µm."),
        (
            "sub-images (1787.52 um across) overlap by 600 um",
            "sub-images (1787.52 µm across) overlap by 600 µm",
        ),
        ("pitch (um): 5 um)", "pitch (µm): 5 µm)"),
        ("an area of 3 um^2,", "an area of 3 µm²,"),
        ("the number is the maximum; minimum", "the number is the maximum; minimum"),  # words with "um"
        ("depth_step_um and center_um", "depth_step_um and center_um"),  # keys
        ("see /data/um/x.tif or um.tif or a.um", "see /data/um/x.tif or um.tif or a.um"),  # paths, files
    ],
)
def test_micrometres_read_as_the_studio_writes_them(text, expected):
    assert shown_units_in(text) == expected


def test_a_refused_field_reads_in_micrometres_as_typed():
    """The walk-through typed "0 µm" into Depth step and read "got 0 um"."""
    outcome = try_changes(load_preset("flfm_guo2019"), {"depths.depth_step_um": 0.0})
    assert not outcome.ok
    assert "Depth step must be a finite number > 0 µm; got 0 µm" in outcome.error
    assert " um" not in outcome.error
