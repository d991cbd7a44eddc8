"""File > Reconstruct light-field video…, the way a user runs it, in the studio started as ``lfm-studio gui``.

The studio opens the small Fourier test design (256 x 256 px, 3 depths); 4 frames of camera
counts imaged through its PSF are saved as a multi-page TIFF. The user opens the File menu entry,
fills the dialog (set here programmatically once it is open) and presses Reconstruct: the job
"video" runs in the background with its progress in the status bar, and at the end the last
frame's volume is a viewer layer and a message names the store and the frame counts. Running it
again into the same store asks before replacing it (declined: nothing runs) and, with "Resume"
ticked, computes nothing. Waits are hang limits only (60 s), never statements about speed.
"""

from __future__ import annotations

import importlib.util
from dataclasses import replace

import numpy as np
import pytest
import tifffile
import torch
from qtpy.QtCore import QSettings, QTimer
from qtpy.QtGui import QGuiApplication
from qtpy.QtWidgets import QMainWindow, QMessageBox

from lfm_studio.engine.batch import extras
from lfm_studio.engine.batch.extras import SCALE_MODULES
from lfm_studio.engine.design import save_design
from lfm_studio.engine.simulation import camera_of, imaging_setup, light_field_image
from lfm_studio.ui.file_menu import FileActions
from lfm_studio.ui.state import StudioState
from lfm_studio.ui.video_dialog import JOB
from lfm_studio.widgets.jobs import JobRunner
from lfm_studio.widgets.viewer import napari_embed
from tests.ui import test_app_end_to_end as end_to_end
from tests.ui.conftest import collect_widgets
from tests.ui.standins import small_fourier_design

callback_errors, torch_threads = end_to_end.callback_errors, end_to_end.torch_threads  # the same fixtures
_launch_like_the_command_line = end_to_end._launch_like_the_command_line
HANG_LIMIT_MS = 60_000
FRAMES = 4

needs_scale = pytest.mark.skipif(
    any(importlib.util.find_spec(name) is None for name in SCALE_MODULES),
    reason="the optional scale extra (dask, zarr, ome-zarr) is not installed",
)


def _wait(qtbot, condition, errors, state) -> None:
    try:
        qtbot.waitUntil(lambda: bool(errors) or bool(condition()), timeout=HANG_LIMIT_MS)
    except qtbot.TimeoutError as timeout:
        raise AssertionError(f"timed out; jobs: {state.jobs}") from timeout
    assert not errors, errors[0]


@pytest.fixture
def studio(qtbot, monkeypatch, tmp_path, callback_errors, torch_threads):
    if QGuiApplication.platformName() in ("offscreen", "minimal") or napari_embed.napari_unavailable_reason():
        pytest.skip("the real napari viewer needs a display with OpenGL (run under pytest-xvfb)")
    design_file = save_design(small_fourier_design(), tmp_path / "small_flfm.json")
    window = _launch_like_the_command_line(monkeypatch, design_file)
    state = window.state
    _wait(qtbot, lambda: state.job("psf").state in ("done", "failed"), callback_errors, state)
    assert state.psf is not None and state.psf.design == state.design
    state.set_workflow(replace(state.workflow, iterations=3))  # the panel's settings are the video's
    yield window
    window.file_actions.confirm_discard = lambda: True  # never block on a dialog in teardown
    window.close()
    collect_widgets()
    assert napari_embed.live_qt_viewers() == 0


@pytest.fixture
def frames_tiff(studio, tmp_path):
    design, stack = studio.state.design, studio.state.psf.stack
    setup = imaging_setup(stack)
    points = (torch.rand(setup.volume_shape, generator=torch.Generator().manual_seed(2)) > 0.998).to(
        stack.data.dtype
    )
    counts = [
        light_field_image(setup, points, camera_of(design), photons=2e5, seed=t)[0] for t in range(FRAMES)
    ]
    path = tmp_path / "recording.tif"
    tifffile.imwrite(path, torch.stack(counts).numpy().astype(np.uint16), photometric="minisblack")
    return path


def _fill(window, frames: str, output: str, *, resume: bool = False) -> list[str]:
    """Fill the modal dialog as soon as it is open and press Reconstruct; returns what it said on the way."""
    said: list[str] = []

    def fill() -> None:
        dialog = window.file_actions.video.dialog
        if dialog is None or not dialog.isVisible():
            QTimer.singleShot(20, fill)
            return
        said.append(dialog.method_label.text())
        dialog.ok_button.click()  # nothing chosen yet: refused, the dialog stays open
        said.append(dialog.error_label.text())
        dialog.frames_edit.setText(frames)
        dialog.output_edit.setText(output)
        dialog.chunk_frames.setText("2")
        dialog.resume.setChecked(resume)
        dialog.ok_button.click()

    QTimer.singleShot(0, fill)
    return said


@needs_scale
def test_reconstruct_a_video_from_the_file_menu(
    qtbot, monkeypatch, studio, frames_tiff, callback_errors, tmp_path
):
    window, state = studio, studio.state
    video = window.file_actions.video
    entries = [a.text() for a in window.menuBar().actions()[0].menu().actions()]
    assert entries.index("Reconstruct light-field &video…") == entries.index("Open &raw light field…") + 1
    out = tmp_path / "run"  # the dialog adds .ome.zarr
    said = _fill(window, str(frames_tiff), str(out))
    window.file_actions.video_action.trigger()  # the File menu entry; returns once the dialog closed
    assert "rl-accelerated, 3 iterations" in said[0] and "small FLFM test design" in said[0]
    assert said[1].startswith("Frames: choose")

    _wait(qtbot, lambda: state.job(JOB).state in ("done", "failed", "cancelled"), callback_errors, state)
    assert state.job(JOB).state == "done", state.job(JOB).message
    assert window.job_status.message.text().startswith("Light-field video: done")
    store = tmp_path / "run.ome.zarr"
    run = video.last_run
    assert run.result.path == str(store) and run.result.computed == tuple(range(FRAMES))
    assert run.shown_frame == FRAMES - 1 and window.viewer.layer("video") is not None
    text = video.last_message.text()
    assert str(store) in text and f"{FRAMES} of {FRAMES} frames" in text and "failed" not in text
    assert float(run.volume.sum()) > 0
    video.last_message.close()

    # The same store again, "Resume" not ticked: the studio asks; "No" runs nothing.
    asked: list[str] = []

    def question(parent, title, text, *args, **kwargs):
        asked.append(text)
        return QMessageBox.StandardButton.No

    monkeypatch.setattr(QMessageBox, "question", question)
    generation = window.controller.runner.generation(JOB)
    _fill(window, str(frames_tiff), str(store))
    assert window.file_actions.video.open() is False
    assert len(asked) == 1 and str(store) in asked[0] and "Resume" in asked[0]
    assert window.controller.runner.generation(JOB) == generation

    # "Resume" ticked: no question, every frame was done before.
    _fill(window, str(frames_tiff), str(store), resume=True)
    window.file_actions.video_action.trigger()
    assert len(asked) == 1
    _wait(qtbot, lambda: window.controller.runner.generation(JOB) > generation and state.job(JOB).state
          in ("done", "failed", "cancelled"), callback_errors, state)  # fmt: skip
    assert state.job(JOB).state == "done", state.job(JOB).message
    assert video.last_run.result.computed == () and video.last_run.result.skipped == tuple(range(FRAMES))
    assert "0 computed now, 4 done before" in video.last_message.text()
    video.last_message.close()
    assert not callback_errors, callback_errors[0]


def test_without_the_scale_extra_the_menu_says_how_to_install_it(qtbot, monkeypatch, tmp_path):
    window = QMainWindow()
    qtbot.addWidget(window)
    state, runner = StudioState(small_fourier_design()), JobRunner(window)
    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    actions = FileActions(state, window, runner, settings=settings)
    monkeypatch.setattr(extras, "SCALE_MODULES", ("lfm_studio_no_such_module",))
    actions.video_action.trigger()
    assert actions.video.dialog is None and runner.generation(JOB) == 0  # no dialog, nothing started
    text = actions.video.last_message.text()
    assert "lfm_studio_no_such_module" in text and 'pip install "lfm-studio[scale]"' in text
    actions.video.last_message.close()
    actions.disconnect_state()


def test_the_dialog_names_the_frame_size_the_projector_images_and_raw_frames_need_a_calibration():
    """A conventional design images whole lenslets: its 128 px camera gives 114 px frames. The label
    said "128 x 128 px camera; frames must match it" while the refusal asked for 114 x 114."""
    from lfm_studio.ui.results import WorkflowSettings
    from lfm_studio.ui.video_dialog import method_text
    from lfm_studio.ui.video_job import frame_shape_fix
    from tests.ui.standins import small_conventional_design

    conventional, fourier = small_conventional_design(), small_fourier_design()
    assert "frames must be 114 x 114 px (what it images of its 128 x 128 px camera)" in method_text(
        WorkflowSettings(), conventional
    )
    assert "frames must be 256 x 256 px (what it images), or raw frames that its Calibration rectifies" in (
        method_text(WorkflowSettings(), fourier)
    )
    fix = frame_shape_fix(conventional)
    assert "Calibration field" in fix and "Open raw light field" in fix


def test_the_calibration_field_is_checked_and_reaches_the_request(qtbot, tmp_path):
    from lfm_studio.ui.results import WorkflowSettings
    from lfm_studio.ui.video_dialog import VideoDialog

    dialog = VideoDialog(None, folder=str(tmp_path))
    qtbot.addWidget(dialog)
    frames = tmp_path / "raw.tif"
    frames.write_bytes(b"")
    dialog.frames_edit.setText(str(frames))
    dialog.output_edit.setText(str(tmp_path / "run"))
    assert (
        dialog.problem() is None
        and dialog.request(small_fourier_design(), WorkflowSettings()).calibration is None
    )
    dialog.calibration_edit.setText(str(tmp_path / "calib.json"))
    assert dialog.problem().startswith("Calibration: ") and "does not exist" in dialog.problem()
    (tmp_path / "calib.json").write_text("{}")
    dialog.counts.setChecked(False)
    assert "tick “Frames are camera counts”" in dialog.problem()
    dialog.counts.setChecked(True)
    assert dialog.problem() is None
    assert dialog.request(small_fourier_design(), WorkflowSettings()).calibration == tmp_path / "calib.json"
