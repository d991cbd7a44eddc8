"""File > Open raw light field…: a real instrument's camera frame as the studio's light-field image.

The dialog asks for the raw camera TIFF and either a calibration file (``lfm-studio
calibrate``) or a radiometry frame (plus an optional dark frame, and an optional file to save
the new calibration to, written only once the frame is in the studio; an existing file is
replaced only after the user agreed, in the file chooser or in a question on OK) to calibrate
against the current design; "Use the calibration's
design" (on by default) offers the design fitted to the calibration: the rectified design of a
conventional LFM, the fitted design of a Fourier LFM, whose PSF images the rectified frame.

:class:`RawFrameActions` runs :func:`~lfm_studio.ui.raw_frames.load_raw_frame` as the job
"raw frame" (progress in the status bar, Cancel stops it; a cancelled or failed load leaves
the studio as it was, a failure gets a dialog). On success, with the calibration's design
accepted, the design is replaced (its PSF is computed as for any edit) and the frame is put
in the studio as the light-field image once that PSF is there, exactly where a simulated
image goes: "Reconstruct" then reconstructs the raw frame (no ground truth to score against).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from qtpy.QtCore import QObject
from qtpy.QtGui import QAction
from qtpy.QtWidgets import (
    QCheckBox,
    QDialog,
    QFileDialog,
    QFormLayout,
    QLineEdit,
    QMessageBox,
    QRadioButton,
    QWidget,
)

from lfm_studio.engine.calibration.calibration_io import calibration_files
from lfm_studio.ui.failure_notices import show_failure
from lfm_studio.ui.path_form import PathFormDialog, path_of, start_folder
from lfm_studio.ui.raw_frames import (
    RawFrame,
    RawFrameRequest,
    load_raw_frame,
    raw_image_result,
    save_made_calibration,
)
from lfm_studio.ui.state import StudioState
from lfm_studio.widgets.jobs import JobOutcome, JobRunner

JOB = "raw frame"
TIFF_FILTER = "TIFF frames (*.tif *.tiff)"
CALIBRATION_FILTER = "Calibration files (*.json)"


class RawFrameDialog(PathFormDialog):
    """The raw frame and its calibration (a file, or a radiometry + dark frame to make one)."""

    def __init__(self, parent: QWidget | None = None, *, folder: str = "") -> None:
        super().__init__(parent, title="Open raw light field", folder=folder)
        self.raw_edit = QLineEdit(self)
        self.use_file = QRadioButton("Calibration file", self)
        self.make_new = QRadioButton("Make a calibration against the current design", self)
        self.use_file.setChecked(True)
        self.calibration_edit = QLineEdit(self)
        self.radiometry_edit = QLineEdit(self)
        self.dark_edit = QLineEdit(self)
        self.dark_edit.setPlaceholderText("optional: same exposure, light blocked")
        self.save_edit = QLineEdit(self)
        self.save_edit.setPlaceholderText("optional: keep the calibration for next time")
        self.agreed_to_replace: Path | None = None  # the save file the file chooser asked about
        self.use_fitted = QCheckBox("Use the calibration's design (its PSF images the rectified frame)", self)
        self.use_fitted.setChecked(True)
        form = QFormLayout()
        form.addRow("Raw camera frame", self._row(self.raw_edit, "Raw camera frame", TIFF_FILTER))
        form.addRow(self.use_file)
        form.addRow("Calibration", self._row(self.calibration_edit, "Calibration file", CALIBRATION_FILTER))
        form.addRow(self.make_new)
        form.addRow("Radiometry frame", self._row(self.radiometry_edit, "Radiometry frame", TIFF_FILTER))
        form.addRow("Dark frame", self._row(self.dark_edit, "Dark frame", TIFF_FILTER))
        form.addRow("Save calibration as", self._row(self.save_edit, "Save calibration as", None))
        self.lay_out(form, self.use_fitted)
        self.use_file.toggled.connect(self._update)
        self._update()

    def _row(self, edit: QLineEdit, title: str, filter_: str | None) -> QWidget:
        return self.path_row(edit, ("Browse…", lambda: self._browse(edit, title, filter_)))

    def _browse(self, edit: QLineEdit, title: str, filter_: str | None) -> None:
        if filter_ is None:  # the calibration to write: the dialog asks before replacing a file
            path, _ = QFileDialog.getSaveFileName(self, title, self.folder, CALIBRATION_FILTER)
            self.agreed_to_replace = Path(path).expanduser() if path else None
        else:
            path, _ = QFileDialog.getOpenFileName(self, title, self.folder, filter_)
        self.chosen(edit, path)

    def _update(self, *_: Any) -> None:
        from_file = self.use_file.isChecked()
        self.calibration_edit.setEnabled(from_file)
        for edit in (self.radiometry_edit, self.dark_edit, self.save_edit):
            edit.setEnabled(not from_file)

    def problem(self) -> str | None:
        """What is missing or wrong (a file that does not exist, named with its field), or None."""
        raw = path_of(self.raw_edit)
        needed = [("Raw camera frame", raw)]
        if self.use_file.isChecked():
            needed.append(("Calibration", path_of(self.calibration_edit)))
        else:
            needed.append(("Radiometry frame", path_of(self.radiometry_edit)))
            dark = path_of(self.dark_edit)
            if dark is not None:
                needed.append(("Dark frame", dark))
        for label, path in needed:
            if path is None:
                return f"{label}: choose a file."
            if not path.is_file():
                return f"{label}: {path} does not exist. Fix: choose an existing file."
        return None

    def request(self, design: Any) -> RawFrameRequest:
        """The load the dialog describes, against ``design``."""
        raw = path_of(self.raw_edit)
        if raw is None:
            raise ValueError("Raw camera frame: choose a file.")
        if self.use_file.isChecked():
            return RawFrameRequest(raw=raw, design=design, calibration=path_of(self.calibration_edit))
        save = path_of(self.save_edit)
        return RawFrameRequest(
            raw=raw,
            design=design,
            radiometry=path_of(self.radiometry_edit),
            dark=path_of(self.dark_edit),
            save_calibration=save,
            overwrite_calibration=save is not None and save == self.agreed_to_replace,
        )


def agreed_request(parent: QWidget, request: RawFrameRequest) -> RawFrameRequest | None:
    """``request``, marked as agreed to replace its existing calibration file once the user said
    Yes; None when the user said No (nothing is loaded). Unchanged when there is nothing to ask."""
    save = request.save_calibration
    existing = [] if save is None or request.overwrite_calibration else calibration_files(save)
    if not existing:
        return request
    names = ", ".join(path.name for path in existing)
    answer = QMessageBox.question(
        parent,
        "Replace calibration?",
        f"{names} already exists. Replace it with the new calibration once the raw frame is open?",
    )
    if answer != QMessageBox.StandardButton.Yes:
        return None
    return dataclasses.replace(request, overwrite_calibration=True)


class RawFrameActions(QObject):
    """The "Open raw light field…" action: dialog, load job, design offer, image installation."""

    def __init__(self, state: StudioState, window: QWidget, runner: JobRunner) -> None:
        super().__init__(window)
        self.state, self.window, self.runner = state, window, runner
        self.action = QAction("Open &raw light field…", self)
        self.action.triggered.connect(self.open)
        self.dialog: RawFrameDialog | None = None  # the open dialog (tests fill it in)
        self.pending: RawFrame | None = None  # loaded, waiting for the PSF of its design
        self.last_failure: QMessageBox | None = None
        self.use_fitted = True
        state.psf_changed.connect(self._on_psf)

    def disconnect_state(self) -> None:
        self.state.psf_changed.disconnect(self._on_psf)

    def open(self, *_: Any) -> bool:
        """Ask for the raw frame and its calibration, then load it on a worker."""
        self.dialog = RawFrameDialog(self.window, folder=start_folder(self.state))
        try:
            if self.dialog.exec() != QDialog.DialogCode.Accepted:
                return False
            request = self.dialog.request(self.state.design)
            use_fitted = self.dialog.use_fitted.isChecked()
        finally:
            self.dialog.deleteLater()
            self.dialog = None
        agreed = agreed_request(self.window, request)
        if agreed is None:
            return False
        self.load(agreed, use_fitted=use_fitted)
        return True

    def load(self, request: RawFrameRequest, *, use_fitted: bool = True) -> None:
        """Start the load job; the studio changes only when it succeeds."""
        self.use_fitted = use_fitted
        self.runner.submit(JOB, load_raw_frame, request, on_result=self._on_loaded, on_error=self._on_failed)

    def _on_loaded(self, frame: RawFrame) -> None:
        self.pending = frame
        if self.use_fitted and frame.psf_design != self.state.design:
            self.state.set_design(frame.psf_design)  # its PSF follows; _on_psf installs the frame
            return
        psf = self.state.psf
        if psf is not None and psf.design == self.state.design and "psf" not in self.state.stale:
            self._install(psf.stack)

    def _on_psf(self, result: Any) -> None:
        frame = self.pending
        if frame is None or result is None or result.preview or result.design != self.state.design:
            return
        if self.use_fitted and result.design != frame.psf_design:  # edited while its PSF was computed
            self.pending = None
            self.last_failure = show_failure(
                self.window,
                "Cannot open raw light field",
                f"the design changed before the PSF of the calibration's design was ready, so "
                f"{frame.request.raw.name} was not opened. Fix: open it again (File > Open raw light field…).",
            )
            return
        self._install(result.stack)

    def _install(self, stack: Any) -> None:
        frame, self.pending = self.pending, None
        if frame is None:
            return
        try:
            image = raw_image_result(frame, stack)
        except ValueError as error:
            self.last_failure = show_failure(self.window, "Cannot open raw light field", str(error))
            return
        self.state.set_reconstruction(None)
        self.state.set_image(image)
        self.state.mark_fresh("image")
        self.state.mark_stale("reconstruction")
        self._save_calibration(frame)

    def _save_calibration(self, frame: RawFrame) -> None:
        """Save the calibration the load made, now that the frame is in the studio."""
        try:
            save_made_calibration(frame)
        except (OSError, ValueError) as error:
            self.last_failure = show_failure(
                self.window,
                "Calibration not saved",
                f"the raw frame is open, but its calibration was not saved: {error}",
            )

    def _on_failed(self, outcome: JobOutcome) -> None:
        error = outcome.error
        self.last_failure = show_failure(
            self.window, "Cannot open raw light field", str(error), details=outcome.details or ""
        )
