"""Dock widget "Reconstruct video": a recording, frame by frame, into an OME-Zarr store, in the background.

A recording is too large to hold as a layer, so the frames are a file (a multi-page TIFF, a
folder of single-frame TIFFs or a Zarr array) that the engine reads lazily, chunk by chunk
(:func:`lfm_studio.engine.batch.reconstruct_video`, docs/scale_out.md). Pick the frames, the
PSF stack TIFF (filled from the PSF layer opened from a file), the method and its options (the
engine's registry, as in "Reconstruct light field"), the output store and how to run: Resume an
interrupted run, worker processes (1: in napari's process; N: a local Dask cluster), whether the
frames are camera counts (converted with the file's camera metadata, else an estimated baseline,
said in a warning) and, for raw frames of a real microscope, their calibration file (each frame
corrected and rectified first; filled from the calibration overlay opened last).

The run is a :class:`~lfm_studio.napari_plugin.background.BackgroundTask`: the progress bar counts
frames, Cancel stops between chunks and leaves a store that Resume finishes (Resume computes the
frames without a record and those recorded as failed). An existing store is continued only with
Resume and replaced only after the user agrees. When the run ends the store is opened lazily as
one multiscale layer (the plugin's OME-Zarr reader) in place of the layers already showing that
store; failed frames are counted first in a warning and in the status line. A failed or cancelled
run adds no layer.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import napari
from napari.layers import Layer
from qtpy.QtWidgets import (
    QCheckBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLineEdit,
    QMessageBox,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.errors import error_text
from lfm_studio.engine.io.file_checks import zarr_store_path
from lfm_studio.napari_plugin.background import BackgroundTask, Outcome
from lfm_studio.napari_plugin.calibration_reader import calibration_source
from lfm_studio.napari_plugin.notify import report_error, report_info, report_warning
from lfm_studio.napari_plugin.reconstruct_widget import is_psf_stack
from lfm_studio.napari_plugin.task_controls import TaskControls
from lfm_studio.widgets.method_options import MethodOptions

MAX_WORKERS = 256
RESUME_FIX = "Tick Resume and run again to compute them."


@dataclass(frozen=True)
class VideoJob:
    """What one run reconstructs (checked on the GUI thread, run on a worker thread).

    Attributes
    ----------
    frames : the recording (multi-page TIFF, folder of TIFFs or Zarr array).
    psf : the PSF stack TIFF.
    output : the OME-Zarr store (``*.zarr``).
    method, options : the registry method and its options.
    resume, overwrite : continue the store's run, or replace the store (the user agreed).
    workers : worker processes (None: in this process).
    counts : the frames are camera counts (converted to photons).
    calibration : raw frames: the calibration file (None: none).
    """

    frames: Path
    psf: Path
    output: Path
    method: str
    options: dict[str, Any]
    resume: bool = False
    overwrite: bool = False
    workers: int | None = None
    counts: bool = True
    calibration: Path | None = None


SHAPE_FIX = (
    "raw frames of a real microscope need their calibration: choose it in the “Calibration (raw frames)” "
    "field (a file from Calibrate or `lfm-studio calibrate`); other frames need the PSF simulated for "
    "this camera in the “PSF stack” field."
)
"""The dock's fix for frames that are not the pixels the PSF images (the engine's shape refusal)."""


def run_video_job(job: VideoJob, progress: Any, cancel: Any) -> Any:
    """The worker-thread body: the camera conversion (noted), then ``reconstruct_video``; returns
    ``(result, notes)``."""
    from lfm_studio.engine.batch import open_frames, reconstruct_video
    from lfm_studio.engine.batch.camera import video_camera

    source = open_frames(job.frames)
    camera, notes = None, []
    if job.counts and job.calibration is None:  # with a calibration the engine converts (baseline 0)
        camera, notes = video_camera(source)
    result = reconstruct_video(
        source, job.psf, method=job.method, options=job.options, output=job.output, resume=job.resume,
        overwrite=job.overwrite, workers=job.workers, camera=camera, calibration=job.calibration,
        progress=lambda done, total, message: progress(done, total, f"{done}/{total} frames ({message})"),
        cancel=cancel, shape_fix=SHAPE_FIX,
    )  # fmt: skip
    return result, notes


def _what_was_kept(job: VideoJob | None) -> str:
    """What a cancelled or failed run left: a replacement leaves the previous store unchanged (the
    engine builds the new one aside), a first or resumed run the chunks it finished."""
    if job is not None and job.overwrite:
        return f"the previous store {job.output.name} is unchanged (the replacement was discarded)."
    return "the store keeps the finished chunks (tick Resume to finish)."


def _path_row(edit: QLineEdit, *buttons: tuple[str, Any]) -> QHBoxLayout:
    row = QHBoxLayout()
    row.addWidget(edit, 1)
    for text, slot in buttons:
        button = QPushButton(text)
        button.clicked.connect(slot)
        row.addWidget(button)
    return row


class VideoWidget(QWidget):
    """The "Reconstruct video" dock widget of ``napari_viewer``."""

    def __init__(self, napari_viewer: napari.viewer.Viewer, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.viewer = napari_viewer
        self.frames = QLineEdit()
        self.frames.setPlaceholderText("a multi-page TIFF, a folder of TIFFs or a Zarr array")
        self.psf = QLineEdit()
        self.psf.setPlaceholderText("PSF stack TIFF (lfm-studio simulate, or Simulate PSF saved)")
        self.output = QLineEdit()
        self.output.setPlaceholderText("run.ome.zarr")
        self.calibration = QLineEdit()
        self.calibration.setPlaceholderText("raw frames only: their calibration .json")
        self.options = MethodOptions()
        self.resume = QCheckBox("Resume a run into this store (only missing or failed frames)")
        self.counts = QCheckBox("Frames are camera counts (ADU)")
        self.counts.setChecked(True)
        self.workers = QSpinBox()
        self.workers.setRange(1, MAX_WORKERS)
        self.workers.setToolTip(
            "1: in napari's process; N > 1: a local Dask cluster of N one-thread processes"
        )
        self.controls = TaskControls("Reconstruct video")
        form = QFormLayout()
        form.addRow(
            "Frames",
            _path_row(self.frames, ("File...", self._browse_frames), ("Folder...", self._browse_folder)),
        )
        form.addRow("PSF stack", _path_row(self.psf, ("Browse...", self._browse_psf)))
        form.addRow(
            "Calibration (raw frames)", _path_row(self.calibration, ("Browse...", self._browse_calibration))
        )
        form.addRow("Output store", _path_row(self.output, ("Browse...", self._browse_output)))
        form.addRow("", self.resume)
        form.addRow("Worker processes", self.workers)
        form.addRow("", self.counts)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(self.options)
        layout.addWidget(self.controls)
        layout.addStretch(1)
        self.controls.runClicked.connect(self.start)
        self._task: BackgroundTask | None = None
        self._job: VideoJob | None = None
        self.last_result: Any = None
        napari_viewer.layers.events.inserted.connect(self._on_layer_inserted)
        for layer in napari_viewer.layers:
            self._on_layer_inserted(layer=layer)

    # ----- the contract (buttons call these; so can tests and scripts) -----

    @property
    def busy(self) -> bool:
        """Whether a video reconstruction is running."""
        return self._task is not None

    def job(self) -> VideoJob:
        """The run the fields describe; a ``ValueError`` naming the field and the fix when refused."""
        frames, psf = (
            self._existing(self.frames, "Frames", "the recording"),
            self._existing(self.psf, "PSF stack", "a PSF stack TIFF"),
        )
        text = self.output.text().strip()
        if not text:
            raise ValueError("Output store: empty. Fix: name the OME-Zarr store to write, e.g. run.ome.zarr.")
        output = zarr_store_path(text)
        if output.exists() and not output.is_dir():
            raise ValueError(f"Output store: {output} is a file, not a Zarr store. Fix: choose another name.")
        if self.resume.isChecked() and not output.exists():
            raise ValueError(
                f"Resume: {output} does not exist yet, so there is nothing to resume. Fix: untick Resume."
            )
        calibration = self._existing(self.calibration, "Calibration", "the calibration .json", optional=True)
        if calibration is not None and not self.counts.isChecked():
            raise ValueError(
                "Calibration: raw frames are camera counts (the calibration subtracts the dark level in ADU). "
                "Fix: tick 'Frames are camera counts', or clear the calibration."
            )
        workers = int(self.workers.value())
        return VideoJob(
            frames, psf, output, self.options.method_name(), dict(self.options.values()),
            resume=self.resume.isChecked(), workers=None if workers == 1 else workers,
            counts=self.counts.isChecked(), calibration=calibration,
        )  # fmt: skip

    def start(self, *, overwrite: bool | None = None) -> bool:
        """Check the fields and start the run; False (with an error notification) if refused or not agreed.

        An existing store without Resume is replaced only when ``overwrite`` is True, or (None) after
        the user agrees in a question."""
        if self._task is not None:
            return False
        from lfm_studio.engine.batch.extras import MissingExtraError, require_scale

        try:
            require_scale()
            job = self.job()
        except (ValueError, MissingExtraError) as error:
            report_error(f"Cannot reconstruct the video: {error_text(error)}")
            return False
        if job.output.exists() and not job.resume:
            agreed = self._ask_replace(job.output) if overwrite is None else overwrite
            if not agreed:
                report_info(f"{job.output} kept: tick Resume to continue its run, or choose another store.")
                self.controls.set_status(f"not run: {job.output.name} kept")
                return False
            job = VideoJob(**{**job.__dict__, "overwrite": True})
        self._job = job
        task = BackgroundTask(lambda progress, cancel: run_video_job(job, progress, cancel), self)
        self.controls.attach(task, f"reconstructing {job.frames.name} into {job.output.name}")
        task.ended.connect(self._on_ended)  # after the controls' slot: the verdict on failed frames stays
        self._task = task
        task.start()
        return True

    def cancel(self) -> None:
        """Stop the run between chunks (the store stays resumable; no layer is added)."""
        self.controls.cancel()

    def set_calibration(self, path: str | Path | None) -> None:
        """Treat the frames as raw frames of the calibration file ``path`` (None: no calibration)."""
        self.calibration.setText("" if path is None else str(path))

    # ----- internals -----

    @staticmethod
    def _existing(edit: QLineEdit, field: str, what: str, *, optional: bool = False) -> Path | None:
        text = edit.text().strip()
        if not text:
            if optional:
                return None
            raise ValueError(f"{field}: empty. Fix: choose {what}.")
        path = Path(text).expanduser()
        if not path.exists():
            raise ValueError(f"{field}: {path} does not exist. Fix: choose {what}.")
        return path

    def _ask_replace(self, path: Path) -> bool:
        answer = QMessageBox.question(
            self, "Replace store?",
            f"{path} already exists. Replace it (every frame is computed again)?\n\nTo continue an "
            "interrupted run instead, choose No and tick Resume.",
        )  # fmt: skip
        return answer == QMessageBox.StandardButton.Yes

    def _browse_frames(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Frames (multi-page TIFF)", "", "TIFF (*.tif *.tiff)")
        if path:
            self.frames.setText(path)

    def _browse_folder(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "Folder of TIFF frames (or a Zarr array)")
        if path:
            self.frames.setText(path)

    def _browse_psf(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "PSF stack", "", "TIFF (*.tif *.tiff)")
        if path:
            self.psf.setText(path)

    def _browse_calibration(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Calibration file", "", "Calibration (*.json)")
        if path:
            self.set_calibration(path)

    def _browse_output(self) -> None:
        path, _ = QFileDialog.getSaveFileName(
            self,
            "Output store",
            "",
            "OME-Zarr (*.ome.zarr *.zarr)",
            options=QFileDialog.Option.DontConfirmOverwrite,
        )  # asked in start()
        if path:
            self.output.setText(str(zarr_store_path(path)))

    def _on_layer_inserted(self, event: Any = None, *, layer: Any = None) -> None:
        """A PSF stack opened from a file fills the PSF field; a calibration overlay the calibration."""
        layer = event.value if layer is None else layer
        source = calibration_source(layer)
        if source is not None:
            self.set_calibration(source)
        path = getattr(getattr(layer, "source", None), "path", None)
        if is_psf_stack(layer) and path:
            self.psf.setText(str(path))

    def _on_ended(self, outcome: Outcome) -> None:
        job, self._task, self._job = self._job, None, None
        if outcome.state == "cancelled":
            report_info(f"Video reconstruction cancelled; {_what_was_kept(job)}")
        elif outcome.state == "failed":
            report_error(f"Video reconstruction failed: {outcome.message} ({_what_was_kept(job)})")
        elif outcome.state == "done" and job is not None:
            result, notes = outcome.value
            self.last_result = result
            for note in notes:
                report_warning(f"{job.frames.name}: {note}")
            self._show(result)

    def _show(self, result: Any) -> None:
        """The store as the one layer of its path, and what the run did (failed frames first)."""
        self._replace_store_layers(result.path)
        failures = _failures_text(result)
        if failures is None:
            report_info(_counts_text(result))
            return
        report_warning(f"{failures} {_counts_text(result)}")
        self.controls.set_status(_failures_status(result))

    def _replace_store_layers(self, store: str | Path) -> None:
        """Open ``store`` lazily in place of the layers already showing it (other layers are kept)."""
        from lfm_studio.napari_plugin.zarr_reader import ome_zarr_layers

        layers = self.viewer.layers
        new = [Layer.create(data, meta, kind) for data, meta, kind in ome_zarr_layers(store, warn=False)]
        old = [layer for layer in layers if _shows_store(layer, store)]
        index = layers.index(old[0]) if old else len(layers)
        for layer in old:
            layers.remove(layer)
        for offset, layer in enumerate(new):
            layers.insert(index + offset, layer)


def _shows_store(layer: Layer, store: str | Path) -> bool:
    """Whether ``layer`` was opened from the OME-Zarr store ``store`` (its metadata "source")."""
    source = layer.metadata.get("source") if isinstance(layer.metadata, dict) else None
    return isinstance(source, str) and Path(source).resolve() == Path(store).resolve()


def _failures_text(result: Any) -> str | None:
    """The failed frames (with their errors) and lost chunks of ``result``; None when there are none."""
    parts = []
    if result.failed:
        listed = "; ".join(f"frame {t}: {error.rstrip('.')}" for t, error in sorted(result.failed.items()))
        parts.append(f"{len(result.failed)} of {result.frame_count} frames failed: {listed}.")
    if result.unfinished:
        parts.append(f"Chunks {list(result.unfinished)} were lost with their worker.")
    return " ".join([*parts, RESUME_FIX]) if parts else None


def _failures_status(result: Any, most: int = 8) -> str:
    """The status line of a run with failed frames or lost chunks (counts and frame numbers only)."""
    parts = []
    if result.failed:
        from lfm_studio.engine.batch.store import listed_frames  # the scale extra ran this result

        parts.append(
            f"{len(result.failed)} of {result.frame_count} frames failed ({listed_frames(result.failed, most)})"
        )
    if result.unfinished:
        parts.append(f"{len(result.unfinished)} chunk(s) lost")
    return f"done with problems: {'; '.join(parts)}. {RESUME_FIX}"


def _counts_text(result: Any) -> str:
    """The store and how many frames it holds reconstructed (now and before), with earlier failures retried."""
    done = len(result.computed) + len(result.skipped)  # lost chunks and failed frames are in neither
    message = (
        f"Store {result.path}: {done} of {result.frame_count} frames reconstructed "
        f"({len(result.computed)} now, {len(result.skipped)} before)."
    )
    retried = result.retried_note()
    return f"{message} {retried}" if retried else message
