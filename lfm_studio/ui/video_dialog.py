"""File > Reconstruct light-field video…: a multi-frame recording into an OME-Zarr store, in the background.

The dialog asks for the frames (a multi-page TIFF or a folder of single-frame TIFFs), the
output store (``*.ome.zarr``), whether to resume an interrupted run into it, the frames per
chunk, the worker processes (1: in the studio's process), whether the frames are camera
counts and, for raw frames of a real microscope, their calibration file (each frame is corrected
and rectified with it, as File > Open raw light field… does for one frame). The reconstruction uses the studio's design and the "Simulate and reconstruct" panel's
method and options (named in the dialog). An existing store is continued only when "Resume"
is ticked, and replaced only after the user said so in a question.

:class:`VideoActions` runs :func:`~lfm_studio.ui.video_job.reconstruct_video_job` as the job
"video" (progress over frames and Cancel in the status bar; a cancelled run leaves a store that
"Resume" finishes). On success the last reconstructed frame's volume is shown in the viewer
(layer "video") and a message names the store, the frame counts and any failed frames with
their errors. Without the optional ``scale`` extra the action says how to install it.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from qtpy.QtCore import QObject
from qtpy.QtGui import QAction
from qtpy.QtWidgets import (
    QCheckBox,
    QDialog,
    QFileDialog,
    QFormLayout,
    QLabel,
    QLineEdit,
    QMessageBox,
    QWidget,
)

from lfm_studio.engine.io.file_checks import zarr_store_path
from lfm_studio.ui.failure_notices import show_failure
from lfm_studio.ui.path_form import PathFormDialog, path_of, start_folder
from lfm_studio.ui.results import JobStatus, WorkflowSettings
from lfm_studio.ui.state import StudioState
from lfm_studio.ui.video_job import DEFAULT_CHUNK_FRAMES, LAYER, VideoRequest, VideoRun, reconstruct_video_job
from lfm_studio.widgets.jobs import JobOutcome, JobRunner
from lfm_studio.widgets.numeric_field import NumericField, commit_all
from lfm_studio.widgets.numeric_text import NumberRule

JOB = "video"
TIFF_FILTER = "TIFF frames (*.tif *.tiff)"
ZARR_FILTER = "OME-Zarr store (*.ome.zarr *.zarr)"
CALIBRATION_FILTER = "Calibration (*.json)"
TITLE = "Reconstruct light-field video"
_Buttons = QMessageBox.StandardButton


class VideoDialog(PathFormDialog):
    """The frames, the output store and how to run (resume, chunk size, workers, counts)."""

    def __init__(self, parent: QWidget | None = None, *, folder: str = "", method_text: str = "") -> None:
        super().__init__(parent, title=TITLE, folder=folder)
        self.frames_edit = QLineEdit(self)
        self.frames_edit.setPlaceholderText("a multi-page TIFF, or a folder of one-frame TIFFs")
        self.output_edit = QLineEdit(self)
        self.output_edit.setPlaceholderText("run.ome.zarr")
        self.resume = QCheckBox(
            "Resume: continue a run into this store (only missing or failed frames)", self
        )
        self.chunk_frames = NumericField(
            NumberRule("Frames per chunk", 1, 100_000, integer=True), DEFAULT_CHUNK_FRAMES, step=1,
            tip="frames per task; each finished chunk is recorded, so a resume restarts at a chunk",
            parent=self,
        )  # fmt: skip
        self.workers = NumericField(
            NumberRule("Worker processes", 1, 256, integer=True), 1, step=1,
            tip="1: in the studio's process; N > 1: a local Dask cluster of N one-thread processes",
            parent=self,
        )  # fmt: skip
        self.counts = QCheckBox(
            "Frames are camera counts (ADU): converted with the file's camera metadata, else the design's camera",
            self,
        )
        self.counts.setChecked(True)
        self.calibration_edit = QLineEdit(self)
        self.calibration_edit.setPlaceholderText("raw frames only: their calibration .json (optional)")
        self.calibration_edit.setToolTip(
            "Raw frames of a real microscope: each frame is dark-subtracted, defect-corrected, flat-fielded "
            "and rectified with this calibration before reconstruction. Leave empty for frames that are "
            "already the pixels the design images."
        )
        self.method_label = QLabel(method_text, self)
        self.method_label.setWordWrap(True)
        form = QFormLayout()
        form.addRow(
            "Frames",
            self.path_row(self.frames_edit, ("File…", self._browse_file), ("Folder…", self._browse_folder)),
        )
        form.addRow("Output store", self.path_row(self.output_edit, ("Browse…", self._browse_output)))
        form.addRow(self.resume)
        form.addRow("Frames per chunk", self.chunk_frames)
        form.addRow("Worker processes", self.workers)
        form.addRow(self.counts)
        form.addRow(
            "Calibration", self.path_row(self.calibration_edit, ("Browse…", self._browse_calibration))
        )
        self.lay_out(form, self.method_label)
        assert self.ok_button is not None
        self.ok_button.setText("Reconstruct")

    def _browse_file(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Frames (multi-page TIFF)", self.folder, TIFF_FILTER)
        self.chosen(self.frames_edit, path)

    def _browse_folder(self) -> None:
        self.chosen(
            self.frames_edit, QFileDialog.getExistingDirectory(self, "Folder of TIFF frames", self.folder)
        )

    def _browse_calibration(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Calibration", self.folder, CALIBRATION_FILTER)
        self.chosen(self.calibration_edit, path)

    def _browse_output(self) -> None:
        path, _ = QFileDialog.getSaveFileName(
            self, "Output store", self.folder, ZARR_FILTER, options=QFileDialog.Option.DontConfirmOverwrite
        )  # the studio asks before replacing a store
        if path:
            self.chosen(self.output_edit, str(zarr_store_path(path)))

    def frames(self) -> Path | None:
        return path_of(self.frames_edit)

    def output(self) -> Path | None:
        text = self.output_edit.text().strip()
        return zarr_store_path(text) if text else None

    def problem(self) -> str | None:
        """What is missing or wrong (named with its field and the fix), or None."""
        frames, output = self.frames(), self.output()
        if frames is None:
            return "Frames: choose a multi-page TIFF or a folder of TIFF frames."
        if not frames.exists():
            return f"Frames: {frames} does not exist. Fix: choose an existing TIFF or folder."
        if output is None:
            return "Output store: choose where to write the OME-Zarr store (e.g. run.ome.zarr)."
        if output.exists() and not output.is_dir():
            return f"Output store: {output} is a file, not a Zarr store. Fix: choose another name."
        if self.resume.isChecked() and not output.exists():
            return f"Resume: {output} does not exist yet, so there is nothing to resume. Fix: untick Resume."
        calibration = path_of(self.calibration_edit)
        if calibration is not None and not calibration.is_file():
            return f"Calibration: {calibration} does not exist. Fix: choose the calibration .json, or clear the field."
        if calibration is not None and not self.counts.isChecked():
            return (
                "Calibration: raw frames are camera counts (the calibration subtracts the dark level in ADU). "
                "Fix: tick “Frames are camera counts”, or clear the calibration."
            )
        if not commit_all((self.chunk_frames, self.workers)):
            return next(str(f.error()) for f in (self.chunk_frames, self.workers) if f.error() is not None)
        return None

    def request(self, design: Any, settings: WorkflowSettings) -> VideoRequest:
        """The run the dialog describes, with ``design`` and the workflow ``settings``."""
        frames, output = self.frames(), self.output()
        if frames is None or output is None:
            raise ValueError("Frames and Output store: choose both.")
        workers = int(self.workers.value())
        return VideoRequest(
            frames, output, design, settings, resume=self.resume.isChecked(),
            chunk_frames=int(self.chunk_frames.value()), workers=None if workers == 1 else workers,
            counts=self.counts.isChecked(), calibration=path_of(self.calibration_edit),
        )  # fmt: skip


def method_text(settings: WorkflowSettings, design: Any) -> str:
    """What the run will use: the workflow panel's method and the studio's design."""
    from lfm_studio.engine.reconstruct import get_method

    takes_iterations = get_method(settings.method).option("iterations") is not None
    iterations = f", {settings.iterations} iterations" if takes_iterations else ""
    options = "".join(f", {k} {v}" for k, v in settings.method_options)
    from lfm_studio.engine.systems.kinds import kind_of

    ny, nx = design.camera.pixel_count
    py, px = kind_of(design).image_shape(design)  # what the video's projector images (no crop)
    camera = "" if (py, px) == (ny, nx) else f" of its {ny} x {nx} px camera"
    return (
        f"Method: {settings.method}{iterations}{options} (the “Simulate and reconstruct” panel's). "
        f"Design: “{design.name}”: frames must be {py} x {px} px (what it images{camera}), or raw frames "
        "that its Calibration rectifies to that."
    )


class VideoActions(QObject):
    """The "Reconstruct light-field video…" action: dialog, background job, result in the viewer."""

    def __init__(self, state: StudioState, window: QWidget, runner: JobRunner, viewer: Any = None) -> None:
        super().__init__(window)
        self.state, self.window, self.runner, self.viewer = state, window, runner, viewer
        self.action = QAction("Reconstruct light-field &video…", self)
        self.action.setToolTip(
            "Reconstruct every frame of a recording into an OME-Zarr store (background job)"
        )
        self.action.triggered.connect(self.open)
        self.dialog: VideoDialog | None = None  # the open dialog (tests fill it in)
        self.last_run: VideoRun | None = None
        self.last_message: QMessageBox | None = None  # the result's message, or the last failure's
        state.job_changed.connect(self._on_job)

    def disconnect_state(self) -> None:
        self.state.job_changed.disconnect(self._on_job)

    def _on_job(self, status: JobStatus) -> None:
        if status.name == JOB:  # a second run would supersede (cancel) the running one
            self.action.setEnabled(not status.active)

    def open(self, *_: Any) -> bool:
        """Ask for the frames and the store, confirm replacing an existing store, then start the job."""
        from lfm_studio.ui.video_job import scale_missing

        missing = scale_missing()
        if missing is not None:
            self.last_message = show_failure(self.window, f"Cannot {TITLE.lower()}", missing)
            return False
        settings = self.state.workflow
        self.dialog = VideoDialog(
            self.window, folder=start_folder(self.state), method_text=method_text(settings, self.state.design)
        )
        try:
            if self.dialog.exec() != QDialog.DialogCode.Accepted:
                return False
            request = self.dialog.request(self.state.design, settings)
        finally:
            self.dialog.deleteLater()
            self.dialog = None
        if request.output.exists() and not request.resume:
            if not self._confirm_replace(request.output):
                return False
            request = replace(request, overwrite=True)
        self.submit(request)
        return True

    def _confirm_replace(self, path: Path) -> bool:
        answer = QMessageBox.question(
            self.window, "Replace store?",
            f"{path} already exists. Replace it (every frame is computed again)?\n\nTo continue an "
            "interrupted run instead, choose No and tick “Resume”.",
            _Buttons.Yes | _Buttons.No, _Buttons.No,
        )  # fmt: skip
        return answer == _Buttons.Yes

    def submit(self, request: VideoRequest) -> int:
        """Start the job "video"; returns its generation."""
        return self.runner.submit(
            JOB, reconstruct_video_job, request, on_result=self._on_done, on_error=self._on_failed
        )

    def _on_done(self, run: VideoRun) -> None:
        self.last_run = run
        if run.display is not None and self.viewer is not None:
            if hasattr(self.viewer, "show_display"):
                self.viewer.show_display(run.display)
            elif hasattr(self.viewer, "show_volume") and run.volume is not None:
                self.viewer.show_volume(run.volume, run.voxel_size, name=LAYER)
        failed = bool(run.result.failed or run.result.unfinished)
        icon = QMessageBox.Icon.Warning if failed else QMessageBox.Icon.Information
        box = QMessageBox(icon, TITLE, run.summary(), QMessageBox.StandardButton.Ok, self.window)
        box.setModal(False)
        box.open()  # never a nested event loop inside a job callback
        self.last_message = box

    def _on_failed(self, outcome: JobOutcome) -> None:
        self.last_message = show_failure(
            self.window, f"Cannot {TITLE.lower()}", str(outcome.error), details=outcome.details or ""
        )
