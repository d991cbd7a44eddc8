"""The raw-frame load (Qt-free job of File > Open raw light field…) for a Fourier LFM, and the dialog's checks.

Scene: :func:`lfm_studio.engine.calibration.synthetic_fourier_scene.misaligned_fourier_scene`
(sub-images turned, scaled, shifted and vignetted per sub-image against ``flfm_guo2019``).
The job makes a calibration from the radiometry and dark frames, names the fitted design, and
converts the frame to photons with baseline 0; the studio's reconstruction stage then
reconstructs it without a ground truth (no scores), close to the true volume.
"""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest
import tifffile
import torch
from qtpy.QtWidgets import QFileDialog

from lfm_studio.engine.calibration import load_calibration
from lfm_studio.engine.calibration.synthetic_fourier_scene import misaligned_fourier_scene
from lfm_studio.engine.image_quality import ncc
from lfm_studio.engine.simulation import simulate_psf
from lfm_studio.ui import pipeline
from lfm_studio.ui.raw_frame_dialog import RawFrameDialog
from lfm_studio.ui.raw_frames import RawFrameRequest, load_raw_frame, raw_image_result, save_made_calibration
from lfm_studio.ui.results import WorkflowSettings


class Ctx:
    """A job context that records progress (what :class:`lfm_studio.widgets.jobs.JobContext` offers)."""

    def __init__(self) -> None:
        self.cancel = threading.Event()
        self.messages: list[str] = []

    def progress(self, done: int, total: int, message: str = "") -> None:
        self.messages.append(message)

    def partial(self, value) -> None:
        pass

    def check(self, message: str = "cancelled") -> None:
        from lfm_studio.engine.progress import CancelledError

        if self.cancel.is_set():
            raise CancelledError(message)


def _tiff(path, frame: torch.Tensor) -> str:
    tifffile.imwrite(path, frame.clamp(0, 65535).round().numpy().astype(np.uint16))
    return str(path)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("raw_frames")
    scene = misaligned_fourier_scene()
    paths = {
        name: _tiff(folder / f"{name}.tif", getattr(scene, name)) for name in ("raw", "radiometry", "dark")
    }
    return scene, paths, folder


def test_a_fourier_raw_frame_is_calibrated_and_reconstructed_without_ground_truth(scene):
    truth_scene, paths, folder = scene
    ctx = Ctx()
    request = RawFrameRequest(
        raw=paths["raw"], design=truth_scene.nominal, radiometry=paths["radiometry"], dark=paths["dark"],
        save_calibration=folder / "calib.json",
    )  # fmt: skip
    frame = load_raw_frame(ctx, request)
    assert any("calibration: sub-image centres" in m for m in ctx.messages)  # the engine's own steps
    assert not (folder / "calib.json").exists()  # saved only once the frame is in the studio
    assert save_made_calibration(frame) == folder / "calib.json"
    assert load_calibration(folder / "calib.json").kind == "fourier"  # saved, as asked
    assert frame.psf_design.name.endswith("(calibrated)") and frame.info["photons"] is None
    assert tuple(frame.photons.shape) == tuple(truth_scene.raw.shape)  # a Fourier frame is not resampled
    # Baseline 0: the dark level (100 ADU, over 100 photons) is gone; the dark corner holds only the
    # read-noise floor the conversion adds (and the reconstruction models as background).
    corner = float(frame.photons[:10, :10].median())
    assert frame.noise_floor > 0 and abs(corner - frame.noise_floor) < 3.0, (corner, frame.noise_floor)
    image = raw_image_result(frame, simulate_psf(frame.psf_design))
    assert image.ground_truth is None
    result = pipeline.reconstruct(Ctx(), frame.psf_design, image, WorkflowSettings(iterations=30))
    assert result.scores is None and result.ncc_curve == () and "no ground truth" in result.summary
    assert len(result.change_curve) == 30
    score = float(ncc(truth_scene.truth, result.volume))
    assert score > 0.95, score  # measured 0.999 (the CLI: 0.998); the all-zero volume scores 0


def test_a_cancelled_load_stops(scene):
    truth_scene, paths, _ = scene
    ctx = Ctx()
    ctx.cancel.set()
    request = RawFrameRequest(raw=paths["raw"], design=truth_scene.nominal, radiometry=paths["radiometry"])
    from lfm_studio.engine.progress import CancelledError

    with pytest.raises(CancelledError):
        load_raw_frame(ctx, request)


class CancelWhenRectifying(Ctx):
    """Cancel (the status bar's button) once the calibration is made, while the frame is rectified."""

    def progress(self, done: int, total: int, message: str = "") -> None:
        super().progress(done, total, message)
        if "rectifying" in message:
            self.cancel.set()


def test_a_load_cancelled_or_failing_after_the_calibration_leaves_the_saved_file(
    scene, tmp_path, monkeypatch
):
    from lfm_studio.engine import calibration
    from lfm_studio.engine.progress import CancelledError

    truth_scene, paths, _ = scene
    saved = tmp_path / "calib.json"
    saved.write_text("the previous calibration")
    request = RawFrameRequest(
        raw=paths["raw"], design=truth_scene.nominal, radiometry=paths["radiometry"], dark=paths["dark"],
        save_calibration=saved, overwrite_calibration=True,
    )  # fmt: skip
    ctx = CancelWhenRectifying()
    with pytest.raises(CancelledError):
        load_raw_frame(ctx, request)
    assert any("calibration: " in m for m in ctx.messages)  # the calibration was made, then cancelled
    assert saved.read_text() == "the previous calibration" and sorted(tmp_path.iterdir()) == [saved]

    def broken(frame, calibration):
        raise ValueError("rectification failed")

    monkeypatch.setattr(calibration, "rectify_frame", broken)
    with pytest.raises(ValueError, match="rectification failed"):
        load_raw_frame(Ctx(), request)
    assert saved.read_text() == "the previous calibration" and sorted(tmp_path.iterdir()) == [saved]


def test_an_existing_calibration_file_is_replaced_only_when_the_user_agreed(
    qtbot, scene, tmp_path, monkeypatch
):
    from qtpy.QtWidgets import QMessageBox

    from lfm_studio.ui.raw_frame_dialog import agreed_request

    truth_scene, paths, _ = scene
    saved = tmp_path / "calib.json"
    request = RawFrameRequest(
        raw=paths["raw"], design=truth_scene.nominal, radiometry=paths["radiometry"], save_calibration=saved
    )
    asked: list[str] = []

    def answer(button):
        def question(parent, title, text, *args, **kwargs):
            asked.append(text)
            return button

        return question

    assert agreed_request(None, request) is request and asked == []  # nothing to replace: no question
    saved.write_text("the previous calibration")
    monkeypatch.setattr(QMessageBox, "question", answer(QMessageBox.StandardButton.No))
    assert agreed_request(None, request) is None  # No: nothing is loaded
    assert asked == [
        "calib.json already exists. Replace it with the new calibration once the raw frame is open?"
    ]
    frame = load_raw_frame(Ctx(), request)
    with pytest.raises(FileExistsError, match=r"calib\.json already exists"):
        save_made_calibration(frame)  # never replaced without the user's agreement
    assert saved.read_text() == "the previous calibration"
    monkeypatch.setattr(QMessageBox, "question", answer(QMessageBox.StandardButton.Yes))
    agreed = agreed_request(None, request)
    assert agreed.overwrite_calibration
    save_made_calibration(dataclasses.replace(frame, request=agreed))
    assert load_calibration(saved).kind == "fourier"
    # The file chooser asked already (Qt's own question): no second question.
    dialog = RawFrameDialog()
    qtbot.addWidget(dialog)
    monkeypatch.setattr(QFileDialog, "getSaveFileName", lambda *a, **k: (str(saved), ""))
    dialog.raw_edit.setText(paths["raw"])
    dialog.make_new.setChecked(True)
    dialog.radiometry_edit.setText(paths["radiometry"])
    dialog._browse(dialog.save_edit, "Save calibration as", None)
    asked.clear()
    assert agreed_request(None, dialog.request(truth_scene.nominal)).overwrite_calibration and asked == []
    typed = tmp_path / "other.json"
    typed.write_text("another calibration")
    dialog.save_edit.setText(str(typed))  # typed over the chosen name: asked
    assert agreed_request(None, dialog.request(truth_scene.nominal)).overwrite_calibration and len(asked) == 1


def test_requests_and_the_dialog_name_what_is_missing(qtbot, scene, tmp_path):
    truth_scene, paths, _ = scene
    with pytest.raises(ValueError, match=r"needs a calibration file or a radiometry frame.*Fix"):
        RawFrameRequest(raw=paths["raw"], design=truth_scene.nominal)
    with pytest.raises(FileNotFoundError, match=r"raw frame .*nope\.tif: no such file\. Fix"):
        request = RawFrameRequest(
            raw=tmp_path / "nope.tif", design=truth_scene.nominal, radiometry=paths["raw"]
        )
        load_raw_frame(Ctx(), request)
    dialog = RawFrameDialog()
    qtbot.addWidget(dialog)
    assert dialog.problem() == "Raw camera frame: choose a file."
    dialog.raw_edit.setText(paths["raw"])
    assert dialog.problem() == "Calibration: choose a file."
    dialog.make_new.setChecked(True)
    assert not dialog.calibration_edit.isEnabled() and dialog.radiometry_edit.isEnabled()
    dialog.radiometry_edit.setText(paths["radiometry"])
    dialog.dark_edit.setText(str(tmp_path / "missing_dark.tif"))
    assert (
        dialog.problem()
        == f"Dark frame: {tmp_path / 'missing_dark.tif'} does not exist. Fix: choose an existing file."
    )
    dialog.accept()
    assert "does not exist" in dialog.error_label.text() and dialog.result() == 0  # still open
    dialog.dark_edit.setText("")
    assert dialog.problem() is None
    request = dialog.request(truth_scene.nominal)
    assert request.radiometry is not None and request.dark is None and request.calibration is None


def test_the_frame_waits_for_its_design_psf_and_an_edit_meanwhile_drops_it(qtbot, scene):
    """The slots of RawFrameActions, driven as the controller drives them (psf_changed)."""
    from types import SimpleNamespace

    from qtpy.QtWidgets import QMainWindow

    from lfm_studio.ui.edits import apply_changes
    from lfm_studio.ui.raw_frame_dialog import RawFrameActions
    from lfm_studio.ui.state import StudioState
    from lfm_studio.widgets.jobs import JobRunner

    truth_scene, paths, _ = scene
    window = QMainWindow()
    qtbot.addWidget(window)
    state = StudioState(truth_scene.nominal)
    runner = JobRunner(window)
    actions = RawFrameActions(state, window, runner)
    request = RawFrameRequest(raw=paths["raw"], design=state.design, radiometry=paths["radiometry"])
    frame = load_raw_frame(Ctx(), request)
    try:
        actions._on_loaded(frame)  # the calibration's design replaces the nominal one; its PSF follows
        assert state.design == frame.psf_design and actions.pending is frame and state.image is None
        stack = simulate_psf(frame.psf_design)
        actions._on_psf(SimpleNamespace(preview=True, design=state.design, stack=stack))  # a preview: wait
        assert state.image is None
        actions._on_psf(SimpleNamespace(preview=False, design=state.design, stack=stack))
        assert state.image is not None and state.image.ground_truth is None and "image" not in state.stale
        assert actions.pending is None
        # Again, but the user edits the design before its PSF is ready: the frame is dropped, with why.
        state.set_image(None)
        actions._on_loaded(frame)  # the design is the calibration's already: waits for a PSF
        edited = apply_changes(state.design, {"wavelength_nm": 600.0})
        state.set_design(edited)
        actions._on_psf(SimpleNamespace(preview=False, design=edited, stack=stack))
        assert actions.pending is None and state.image is None
        assert "design changed before" in actions.last_failure.text()
        actions.last_failure.close()
    finally:
        actions.disconnect_state()
        runner.shutdown()
