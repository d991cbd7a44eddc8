"""The application state, design edits and stage helpers: Qt-free (no QApplication here)."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import pytest

from lfm_studio.engine.design import load_preset
from lfm_studio.ui import pipeline
from lfm_studio.ui.edits import apply_changes, try_changes
from lfm_studio.ui.results import STAGES, WorkflowSettings
from lfm_studio.ui.state import MAX_RECENT_FILES, StudioState, stages_affected
from tests.ui.standins import small_fourier_design


@pytest.fixture(scope="module")
def design():
    return small_fourier_design()


class Recorder:
    """Collects what a psygnal signal emits."""

    def __init__(self, signal):
        self.values = []
        signal.connect(self.values.append)


def test_state_modules_import_no_qt():
    probe = (
        "import sys, lfm_studio.ui.state, lfm_studio.ui.edits, lfm_studio.ui.pipeline, lfm_studio.ui.results;"
        "print(','.join(m for m in ('PySide6', 'qtpy', 'napari', 'pyqtgraph') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == ""


def test_a_new_design_is_put_in_force_marks_every_stage_stale_and_dirty(design):
    state = StudioState(design)
    for stage in STAGES:
        state.mark_fresh(stage)
    changed, stale = Recorder(state.design_changed), Recorder(state.stale_changed)
    new = apply_changes(design, {"objective.numerical_aperture": 0.9})
    assert state.set_design(new)
    assert changed.values == [new] and state.design is new and state.last_valid_design is new
    assert stale.values[-1] == frozenset(STAGES)
    assert state.dirty
    assert not state.set_design(apply_changes(design, {"objective.numerical_aperture": 0.9}))  # equal: no-op
    assert len(changed.values) == 1


def test_only_the_stages_a_change_touches_become_stale(design):
    noise = apply_changes(design, {"camera.read_noise_e": 3.0})
    renamed = apply_changes(design, {"name": "renamed"})
    moved = apply_changes(design, {"mla.lenslets.0.focal_length_mm": 17.0})
    assert stages_affected(design, noise) == ("image", "reconstruction")
    assert stages_affected(design, renamed) == ()
    assert stages_affected(design, moved) == STAGES
    state = StudioState(design)
    for stage in STAGES:
        state.mark_fresh(stage)
    state.set_design(noise)
    assert state.stale == {"image", "reconstruction"}


def test_workflow_changes_mark_the_image_or_only_the_reconstruction_stale(design):
    state = StudioState(design)
    for stage in STAGES:
        state.mark_fresh(stage)
    state.set_workflow(WorkflowSettings(iterations=3))
    assert state.stale == {"reconstruction"}
    state.mark_fresh("reconstruction")
    state.set_workflow(WorkflowSettings(iterations=3, seed=5))
    assert state.stale == {"image", "reconstruction"}


def test_field_errors_are_recorded_and_cleared_with_signals(design):
    state = StudioState(design)
    errors = Recorder(state.errors_changed)
    state.set_field_error("objective.numerical_aperture", "too large")
    state.set_field_error("objective.numerical_aperture", "too large")  # same: no second signal
    assert state.errors == {"objective.numerical_aperture": "too large"}
    state.clear_errors(["objective.numerical_aperture"])
    assert state.errors == {} and errors.values == [{"objective.numerical_aperture": "too large"}, {}]


def test_replace_design_starts_a_clean_document(design, tmp_path):
    state = StudioState(design)
    state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))
    state.set_field_error("wavelength_nm", "bad")
    state.set_metrics(object())
    replaced = Recorder(state.design_replaced)
    other = load_preset("xlfm_cong2017")
    state.replace_design(other, file_path=tmp_path / "x.json")
    assert state.design is other and replaced.values == [other]
    assert not state.dirty and state.errors == {} and state.metrics is None and state.psf is None
    assert state.file_path == tmp_path / "x.json" and state.stale == frozenset(STAGES)


def test_recent_files_are_unique_newest_first_and_bounded(design, tmp_path):
    state = StudioState(design)
    paths = [tmp_path / f"d{i}.json" for i in range(MAX_RECENT_FILES + 3)]
    for p in paths:
        state.add_recent_file(p)
    state.add_recent_file(paths[-2])
    assert state.recent_files[0] == paths[-2]
    assert len(state.recent_files) == MAX_RECENT_FILES and len(set(state.recent_files)) == MAX_RECENT_FILES
    state.mark_saved(paths[0])
    assert state.recent_files[0] == paths[0] and state.file_path == paths[0] and not state.dirty


def test_an_invalid_edit_is_refused_with_the_design_error_text(design):
    outcome = try_changes(design, {"objective.numerical_aperture": 1.2})  # air objective: NA < 1
    assert not outcome.ok and outcome.design is None
    assert "Numerical aperture 1.2 must be below immersion index 1" in outcome.error  # the studio's labels
    assert "validation error" not in outcome.error and "pydantic" not in outcome.error


def test_pending_values_are_applied_together_in_one_validation(design):
    # NA 1.2 alone is refused; with water immersion at the same time it is valid.
    outcome = try_changes(design, {"objective.numerical_aperture": 1.2, "objective.immersion_index": 1.333})
    assert outcome.ok
    assert outcome.design.objective.numerical_aperture == 1.2
    assert outcome.design.objective.immersion_index == 1.333
    assert design.objective.numerical_aperture == 0.95  # the input design is untouched (frozen)


def test_design_warnings_are_collected_not_raised(design):
    # A 200 px sensor cuts the sub-images: a DesignWarning (an error under pytest's filter if raised).
    outcome = try_changes(design, {"camera.pixel_count": (200, 200)})
    assert outcome.ok
    assert any("cut by the edge" in w for w in outcome.warnings)


def test_preview_of_a_big_design_is_binned_with_few_depths():
    xlfm = load_preset("xlfm_cong2017")
    request = pipeline.PSFRequest.for_design(xlfm)
    assert request.preview is not None
    assert request.preview.camera.pixel_count == (1024, 1024)
    assert request.preview.camera.pixel_pitch_um == pytest.approx(2 * xlfm.camera.pixel_pitch_um)
    assert request.preview.accuracy.preset == "preview"
    depths_um = [z * 1e6 for z in request.preview_depths]
    assert depths_um == pytest.approx([-200, -100, 0, 100, 200], abs=1e-9)


def test_a_small_design_needs_no_preview(design):
    assert pipeline.PSFRequest.for_design(design).preview is None


def test_a_run_asked_for_again_is_stale_but_not_outdated(design):
    state = StudioState(design)
    emitted = []
    state.stale_changed.connect(emitted.append)
    for stage in STAGES:
        state.mark_fresh(stage)
    assert state.stale == state.outdated == frozenset()
    version = state.inputs_version("reconstruction")
    state.mark_stale("reconstruction", changed=False)  # the button pressed again
    assert state.stale == {"reconstruction"} and state.outdated == frozenset()
    assert state.inputs_version("reconstruction") == version
    state.set_workflow(replace(state.workflow, iterations=state.workflow.iterations + 1))  # a change
    assert state.outdated == {"reconstruction"} and state.inputs_version("reconstruction") == version + 1
    count = len(emitted)
    state.set_workflow(replace(state.workflow, iterations=state.workflow.iterations + 1))
    assert len(emitted) == count + 1  # a new inputs version is announced though the stale set is the same
    state.mark_fresh("reconstruction")
    assert state.stale == state.outdated == frozenset()


def test_options_left_out_or_written_out_at_their_defaults_are_the_same_settings():
    """The workflow panel writes every option of the method (at its default); the state started with
    none: the first press of Reconstruct counted as a change of settings."""
    from lfm_studio.engine.reconstruct import get_method

    plain = WorkflowSettings()
    written_out = replace(plain, method_options=tuple(sorted(
        (k, v) for k, v in get_method(plain.method).defaults().items() if k not in ("iterations", "background")
    )))  # fmt: skip
    assert written_out.method_options and not plain.reconstruction_changed(written_out)
    assert plain.reconstruction_changed(replace(plain, method_options=(("tv_weight", 0.01),)))
    state = StudioState(small_fourier_design())
    state.mark_fresh("reconstruction")
    state.set_workflow(written_out)
    assert "reconstruction" not in state.stale
