"""Stale marks (issue 20): a result on screen that no longer matches the design is marked stale.

The marks computed from constructed states (no jobs), then the studio window with the real
viewer (pyqtgraph fallback and napari) on the small Fourier design: a PSF job that is
recomputing and then fails leaves the previous PSF marked "stale" with the error in the
viewer's banner and the plots; a fresh result clears every mark; no exception reaches a slot.
"""

from __future__ import annotations

import sys
import threading
from dataclasses import replace
from types import SimpleNamespace

import pytest
from qtpy.QtCore import QSettings
from qtpy.QtWidgets import QApplication

from lfm_studio.ui import pipeline
from lfm_studio.ui.app import build_studio
from lfm_studio.ui.edits import apply_changes
from lfm_studio.ui.plots import ConvergencePlot
from lfm_studio.ui.results import JobStatus
from lfm_studio.ui.stale_marks import StaleMarks, metrics_mark, stage_mark
from lfm_studio.ui.state import StudioState
from lfm_studio.widgets.psf_viewer import PSFViewer
from lfm_studio.widgets.stale_mark import StaleMark
from tests.ui.conftest import collect_widgets
from tests.ui.standins import FakeMLAEditor, small_fourier_design

TIMEOUT_MS = 60_000  # only a hang should reach it
ERROR = "not enough memory for 3 depths (test)"


@pytest.fixture(scope="module")
def design():
    return small_fourier_design()


def test_marks_follow_staleness_jobs_and_results(design):
    state = StudioState(design)
    assert stage_mark(state, "psf") is None  # nothing shown, nothing failed: nothing to mark
    state.set_job(JobStatus("psf", "failed", message="failed: disk full"))
    assert stage_mark(state, "psf").text == "PSF failed: disk full"  # nothing shown, but the failure is said
    state.set_psf(SimpleNamespace(design=design))
    state.mark_fresh("psf")
    assert stage_mark(state, "psf") is None and metrics_mark(state) is None  # fresh
    state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))
    assert state.stale == {"psf", "image", "reconstruction"}
    assert stage_mark(state, "psf").text == "stale: shows the previous design; PSF failed: disk full"
    state.set_job(JobStatus("psf", "running", 1, 4, "lenslet 1/4", generation=2))
    assert stage_mark(state, "psf").text == "stale: shows the previous design; recomputing…"
    assert (
        metrics_mark(state).text == "formula estimates only: measured values wait for the PSF (recomputing…)"
    )
    state.set_job(JobStatus("psf", "cancelled", generation=2))
    assert stage_mark(state, "psf").text == "stale: shows the previous design; PSF cancelled"
    assert metrics_mark(state).text == "formula estimates only: PSF cancelled"
    state.set_preview(SimpleNamespace(design=state.design))  # the new design's quick preview
    state.set_job(JobStatus("psf", "running", generation=3))
    assert stage_mark(state, "psf").text == "quick preview of this design; full PSF: recomputing…"
    assert stage_mark(state, "image") is None  # no image shown
    state.set_image(SimpleNamespace(design=design))
    assert stage_mark(state, "image").text == "stale: made with the previous design or settings"
    with pytest.raises(ValueError, match="stage must be one of"):
        stage_mark(state, "metrics")


def test_a_result_is_not_marked_when_only_a_run_was_asked_for_again(design):
    """ "stale: made with the previous design or settings" showed when the button was pressed again."""
    state = StudioState(design)
    state.set_image(SimpleNamespace(design=design))
    state.set_reconstruction(SimpleNamespace(ncc_curve=(0.5,), change_curve=(0.1,)))
    for stage in ("psf", "image", "reconstruction"):
        state.mark_fresh(stage)
    state.mark_stale("image", "reconstruction", changed=False)  # Simulate image pressed again
    state.set_job(JobStatus("reconstruction", "running", 1, 4, "iteration 1 of 4", generation=2))
    assert stage_mark(state, "image") is None and stage_mark(state, "reconstruction") is None
    state.set_job(JobStatus("reconstruction", "failed", message="failed: RL diverged", generation=2))
    assert stage_mark(state, "reconstruction") is None  # the panel's message line says why
    state.set_workflow(replace(state.workflow, seed=state.workflow.seed + 1))  # now a change
    head = "stale: made with the previous design or settings"
    assert stage_mark(state, "image").text == head
    assert stage_mark(state, "reconstruction").text == f"{head}; reconstruction failed: RL diverged"


class _MarkRecorder:
    def __init__(self):
        self.marks: dict[str, str] = {}

    def set_stale_marks(self, marks):
        self.marks = {layer: mark.text for layer, mark in marks.items()}


def test_image_and_reconstruction_marks_reach_their_layers_and_the_convergence_plot(qtbot, design):
    state = StudioState(design)
    viewer, plot = _MarkRecorder(), ConvergencePlot(state)
    qtbot.addWidget(plot)
    marks = StaleMarks(state, viewer=viewer, convergence=plot)
    state.set_image(SimpleNamespace(design=design))
    state.set_reconstruction(SimpleNamespace(ncc_curve=(0.2, 0.5), change_curve=(0.1, 0.05)))
    for stage in ("psf", "image", "reconstruction"):
        state.mark_fresh(stage)
    assert viewer.marks == {} and plot.stale_text is None and not plot.is_dimmed()
    state.set_workflow(replace(state.workflow, iterations=state.workflow.iterations + 5))
    assert state.stale == {"reconstruction"}  # only the reconstruction depends on the iterations
    head = "stale: made with the previous design or settings"
    assert viewer.marks == {"reconstruction": head}
    assert plot.stale_text == head and plot.is_dimmed()
    state.set_job(JobStatus("reconstruction", "failed", message="failed: RL diverged"))
    assert plot.stale_text == f"{head}; reconstruction failed: RL diverged"
    state.set_design(apply_changes(design, {"camera.read_noise_e": 2.0}))  # noise: same PSF, new image
    assert set(viewer.marks) == {"light field", "phantom", "reconstruction"}
    state.mark_fresh("image")
    state.mark_fresh("reconstruction")
    assert viewer.marks == {} and plot.stale_text is None and not plot.is_dimmed()
    marks.disconnect_state()
    plot.disconnect_state()


def _gated_failure(entered: threading.Event, gate: threading.Event):
    def compute_psf(ctx, request, cache):
        entered.set()
        while not gate.wait(0.01):
            ctx.check()  # a cancel still stops it
        raise RuntimeError(ERROR)

    return compute_psf


def _canvas_note(viewer) -> str | None:
    """napari: the canvas read-out's text after the slice position (None with the fallback)."""
    if viewer.backend != "napari":
        return None
    text = viewer._scene.model.canvas.overlays.text.text
    return text.split("µm")[-1].strip()  # "PSF   z = +0.0 µm   STALE (failed)" -> "STALE (failed)"


@pytest.mark.parametrize("backend", ["pyqtgraph", "napari"])
def test_a_failed_psf_leaves_the_previous_one_marked_stale_until_a_fresh_one(
    qtbot, tmp_path, design, monkeypatch, backend
):
    hooked: list[BaseException] = []
    monkeypatch.setattr(sys, "excepthook", lambda kind, value, tb: hooked.append(value))
    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    window = build_studio(
        design, settings=settings, preview=False, debounce_ms=10,
        editor_factory=lambda d: FakeMLAEditor(d.mla.lenslets),
        viewer_factory=lambda: PSFViewer(use_napari=backend == "napari"),
    )  # fmt: skip
    window.show()
    qtbot.waitExposed(window)
    state, controller, viewer = window.state, window.controller, window.viewer
    views = (window.profiles, window.requirements)
    assert viewer.backend == backend
    try:
        controller.start()
        qtbot.waitUntil(lambda: state.psf is not None and "psf" not in state.stale, timeout=TIMEOUT_MS)
        qtbot.waitUntil(lambda: not state.job("psf").active, timeout=TIMEOUT_MS)
        first = state.psf
        assert viewer.layer_names() == ["PSF"]
        assert viewer.stale_text is None and [v.stale_text for v in views] == [None, None]
        assert not window.profiles.is_dimmed()

        entered, gate = threading.Event(), threading.Event()
        monkeypatch.setattr(pipeline, "compute_psf", _gated_failure(entered, gate))
        state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))
        controller.flush()
        assert entered.wait(60)
        qtbot.waitUntil(lambda: state.job("psf").active, timeout=TIMEOUT_MS)
        assert viewer.stale_text == "PSF: stale: shows the previous design; recomputing…"
        assert window.profiles.stale_text == "stale: shows the previous design; recomputing…"
        assert window.profiles.is_dimmed()
        assert "measured values wait for the PSF" in window.requirements.stale_text

        gate.set()
        qtbot.waitUntil(lambda: state.job("psf").state == "failed", timeout=TIMEOUT_MS)
        assert state.psf is first  # the last good PSF stays on screen ...
        expected = f"stale: shows the previous design; PSF failed: {ERROR}"
        assert viewer.stale_text == f"PSF: {expected}"  # ... marked stale, with the error
        assert window.profiles.stale_text == expected and window.profiles.is_dimmed()
        napari = backend == "napari"
        assert _canvas_note(viewer) == ("STALE (failed)" if napari else None)  # napari: also on the canvas
        assert window.requirements.stale_text == f"formula estimates only: PSF failed: {ERROR}"
        if window.failure_notices.last is not None:
            window.failure_notices.last.close()

        monkeypatch.undo()  # the real pipeline again (and the real excepthook: re-install ours)
        monkeypatch.setattr(sys, "excepthook", lambda kind, value, tb: hooked.append(value))
        fixed = apply_changes(design, {"wavelength_nm": 690.0})
        state.set_design(fixed)
        controller.flush()
        qtbot.waitUntil(lambda: state.psf.design == fixed and "psf" not in state.stale, timeout=TIMEOUT_MS)
        assert viewer.stale_text is None  # the fresh result clears every mark
        assert _canvas_note(viewer) == ("" if napari else None)
        assert [v.stale_text for v in views] == [None, None] and not window.profiles.is_dimmed()
        assert hooked == []
    finally:
        controller.cancel()
        state.set_dirty(False)
        with qtbot.waitSignal(window.destroyed, timeout=TIMEOUT_MS):
            assert window.close()
        QApplication.sendPostedEvents(None, 0)
        collect_widgets()


def test_marks_carry_their_colour_and_short_form_from_the_job_state_not_from_the_text(design):
    state = StudioState(design)
    state.set_preview(SimpleNamespace(design=design))  # the current design's quick preview is shown
    state.mark_stale("psf")
    # An error message full of the words a text search would look for changes nothing.
    state.set_job(JobStatus("psf", "failed", message="failed: cancelled while recomputing"))
    mark = stage_mark(state, "psf")
    assert mark.text == "quick preview of this design; full PSF: PSF failed: cancelled while recomputing"
    assert (mark.preview, mark.activity, mark.short) == (True, "failed", "PREVIEW (full PSF failed)")
    assert mark.colours == StaleMark("x", "failed").colours != StaleMark("x").colours
    state.set_job(JobStatus("psf", "running", message="failed earlier"))
    mark = stage_mark(state, "psf")
    assert (mark.activity, mark.short, mark.colours) == (
        "recomputing",
        "PREVIEW (full PSF computing)",
        StaleMark("x").colours,
    )


def test_the_canvas_calls_a_preview_of_the_current_design_a_preview_not_stale():
    assert StaleMark("quick preview…", "recomputing", preview=True).short == "PREVIEW (full PSF computing)"
    assert StaleMark("quick preview…", preview=True).short == "PREVIEW"
    assert StaleMark("stale: …", "recomputing").short == "STALE (recomputing)"
    assert StaleMark("stale: …", "failed").short == "STALE (failed)"
    assert StaleMark("stale: …").short == "STALE"
