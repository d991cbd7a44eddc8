"""File > Open raw light field…, the way a user runs it, in the studio started as ``lfm-studio gui``.

Scene (:func:`lfm_studio.engine.calibration.synthetic_scene.misaligned_bead_scene`): six beads
in 3 depths of ``lfm_10x_na03`` (8 x 8 lenslets of 19 px on the model's lattice) seen through a
raw camera with 19.37 x 19.31 px lenslets, a 1.5 deg rotation, an offset, vignetting, noise, a
100 ADU dark offset and hot pixels. The studio opens the instrument's nominal design; the user
opens the raw frame, makes a calibration from the radiometry and dark frames, accepts the
calibration's design, and presses "Reconstruct". Reference: the same beads reconstructed from
the aligned frame through the CLI measured NCC 0.976 (calibrated 0.950; an uncalibrated crop
-0.002; tests/cli/test_reconstruct_calibrated_cli.py); the studio's 10 accelerated RL
iterations must reach 0.8, far above the all-zero and constant volumes' 0.
"""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
import torch
from qtpy.QtCore import QTimer
from qtpy.QtGui import QGuiApplication

from lfm_studio.engine.calibration import load_calibration
from lfm_studio.engine.calibration.synthetic_scene import misaligned_bead_scene
from lfm_studio.engine.design import save_design
from lfm_studio.engine.image_quality import ncc
from lfm_studio.ui.raw_frame_dialog import JOB
from lfm_studio.ui.raw_frames import RawFrameRequest
from lfm_studio.widgets.viewer import napari_embed
from tests.ui import test_app_end_to_end as end_to_end
from tests.ui.conftest import collect_widgets

_launch_like_the_command_line, _wait = end_to_end._launch_like_the_command_line, end_to_end._wait
callback_errors, torch_threads = end_to_end.callback_errors, end_to_end.torch_threads  # the same fixtures


def _tiff(path, frame: torch.Tensor) -> str:
    tifffile.imwrite(path, frame.clamp(0, 65535).round().numpy().astype(np.uint16))
    return str(path)


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory):
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("raw_light_field")
    scene = misaligned_bead_scene()
    torch.set_num_threads(threads)
    return {
        "folder": folder,
        "scene": scene,
        "nominal": str(save_design(scene.nominal, folder / "nominal.json")),
        "raw": _tiff(folder / "raw.tif", scene.raw),
        "radiometry": _tiff(folder / "radiometry.tif", scene.radiometry),
        "dark": _tiff(folder / "dark.tif", scene.dark),
        "blank": _tiff(
            folder / "blank.tif", torch.full(scene.raw.shape, 100.0) + torch.rand(scene.raw.shape)
        ),
    }


@pytest.fixture
def studio(qtbot, monkeypatch, scene_files, callback_errors, torch_threads):
    if QGuiApplication.platformName() in ("offscreen", "minimal") or napari_embed.napari_unavailable_reason():
        pytest.skip("the real napari viewer needs a display with OpenGL (run under pytest-xvfb)")
    window = _launch_like_the_command_line(monkeypatch, scene_files["nominal"])
    state = window.state
    _wait(qtbot, lambda: state.job("psf").state in ("done", "failed"), callback_errors, state)
    assert state.psf is not None and state.psf.design == state.design
    yield window
    window.file_actions.confirm_discard = lambda: True  # never block on a dialog in teardown
    window.close()
    collect_widgets()
    assert napari_embed.live_qt_viewers() == 0


def _fill_dialog(window, fields: dict[str, str], use_fitted: bool = True, make: bool = True) -> list[str]:
    """Fill the modal dialog as soon as it is open and press OK; returns what it said on the way."""
    said: list[str] = []

    def fill() -> None:
        dialog = window.file_actions.raw_frames.dialog
        if dialog is None or not dialog.isVisible():
            QTimer.singleShot(20, fill)
            return
        (dialog.make_new if make else dialog.use_file).setChecked(True)
        dialog.raw_edit.setText(fields["raw"])
        dialog.ok_button.click()  # without the calibration's files: refused, the dialog stays open
        said.append(dialog.error_label.text())
        for name, edit in (
            ("calibration", dialog.calibration_edit),
            ("radiometry", dialog.radiometry_edit),
            ("dark", dialog.dark_edit),
            ("save", dialog.save_edit),
        ):
            edit.setText(fields.get(name, ""))
        dialog.use_fitted.setChecked(use_fitted)
        dialog.ok_button.click()

    QTimer.singleShot(0, fill)
    return said


def test_open_a_raw_frame_calibrate_it_and_reconstruct(qtbot, studio, scene_files, callback_errors, tmp_path):
    window, state = studio, studio.state
    nominal = state.design
    saved = tmp_path / "calib.json"
    fields = {"raw": scene_files["raw"], "radiometry": scene_files["radiometry"], "dark": scene_files["dark"]}
    said = _fill_dialog(window, {**fields, "save": str(saved)})
    assert "Open &raw light field…" in [a.text() for a in window.menuBar().actions()[0].menu().actions()]
    window.file_actions.open_raw_action.trigger()  # the File menu entry; returns once the dialog closed
    assert said == ["Radiometry frame: choose a file."]

    # The calibration runs as a job; then the calibration's design replaces the nominal one, its PSF
    # is computed like any edit's, and the rectified frame becomes the studio's light-field image.
    _wait(qtbot, lambda: state.image is not None or state.job(JOB).state == "failed", callback_errors, state)
    assert state.job(JOB).state == "done", state.job(JOB).message
    assert state.design != nominal and state.design.name.endswith("(rectified)")
    assert state.psf.design == state.design and "image" not in state.stale
    image = state.image
    assert image.ground_truth is None and tuple(image.counts.shape) == (152, 152)  # 8 x 8 lenslets of 19 px
    assert image.info["raw_frame"] == scene_files["raw"] and float(image.counts.sum()) > 0
    assert window.viewer.layer("light field") is not None
    calibration = load_calibration(saved)  # kept for next time, as asked
    assert calibration.grid.lattice.pitch == pytest.approx((19.37, 19.31), abs=0.01)

    window.workflow_panel.reconstruct_button.click()
    _wait(qtbot, lambda: state.job("reconstruction").state in ("done", "failed"), callback_errors, state)
    assert state.job("reconstruction").state == "done", state.job("reconstruction").message
    volume = state.reconstruction.volume
    truth = scene_files["scene"].truth
    assert volume.shape == truth.shape
    score = float(ncc(truth, volume))
    assert score > 0.8, score  # measured 0.878; the all-zero and constant volumes score 0
    assert state.reconstruction.scores is None and "no ground truth" in state.reconstruction.summary
    quality = window.workflow_panel.quality.text()  # said on screen, not a row of dashes
    assert quality.startswith("Reconstructed after ") and "a recorded frame has no ground truth" in quality
    assert window.viewer.layer("reconstruction") is not None
    assert not callback_errors, callback_errors[0]


def test_declining_the_calibration_design_is_refused_with_both_shapes(
    qtbot, studio, scene_files, callback_errors
):
    window, state = studio, studio.state
    nominal = state.design
    calib = scene_files["folder"] / "calib_for_decline.json"
    from lfm_studio.engine.calibration import calibrate, save_calibration

    save_calibration(
        calibrate(scene_files["scene"].radiometry, nominal, dark=scene_files["scene"].dark), calib
    )
    _fill_dialog(window, {"raw": scene_files["raw"], "calibration": str(calib)}, use_fitted=False, make=False)
    window.file_actions.open_raw_action.trigger()
    raw_frames = window.file_actions.raw_frames
    _wait(qtbot, lambda: raw_frames.last_failure is not None, callback_errors, state)
    text = raw_frames.last_failure.text()
    assert (
        "(152, 152) pixels" in text
        and "PSF images (171, 171)" in text  # the nominal design: 9 x 9 lenslets of 19 px
        and "Fix: open it again with the calibration" in text
    )
    raw_frames.last_failure.close()
    assert state.design == nominal and state.image is None  # nothing changed


def test_a_failed_or_cancelled_calibration_leaves_the_studio_as_it_was(
    qtbot, studio, scene_files, callback_errors
):
    window, state = studio, studio.state
    raw_frames = window.file_actions.raw_frames
    before = (state.design, state.psf, state.image)
    # A radiometry frame without a lenslet grid: the engine's named error, in a dialog.
    request = RawFrameRequest(raw=scene_files["raw"], design=state.design, radiometry=scene_files["blank"])
    raw_frames.load(request)
    _wait(qtbot, lambda: state.job(JOB).state in ("done", "failed"), callback_errors, state)
    assert state.job(JOB).state == "failed"
    assert "Fix" in raw_frames.last_failure.text()
    raw_frames.last_failure.close()
    assert (state.design, state.psf, state.image) == before
    # Cancel (the status bar's button) while it calibrates.
    request = RawFrameRequest(
        raw=scene_files["raw"],
        design=state.design,
        radiometry=scene_files["radiometry"],
        dark=scene_files["dark"],
    )
    raw_frames.load(request)
    window.job_status.cancel_requested.emit()
    _wait(qtbot, lambda: state.job(JOB).state in ("done", "failed", "cancelled"), callback_errors, state)
    assert state.job(JOB).state == "cancelled"
    qtbot.wait(50)
    assert (state.design, state.psf, state.image) == before and raw_frames.pending is None
