"""Dock widget "Calibrate": a radiometry frame (and a dark frame) -> the fitted lenslet grid, in the background.

Pick a radiometry image layer (a uniform fluorescent slide seen through the MLA), an
optional dark image layer (same exposure, light blocked) and the nominal design (a
bundled preset or a design file), then Calibrate: :func:`~lfm_studio.engine.calibration.calibrate`
runs as a :class:`~lfm_studio.napari_plugin.background.BackgroundTask` (a job of
:class:`lfm_studio.widgets.jobs.JobRunner`) with progress and Cancel (cancel adds nothing). When it
is done the fitted-grid overlay is added, the same two Points layers the calibration reader
makes (:func:`~lfm_studio.napari_plugin.calibration_reader.overlay_layer_data`; residuals and
flags in the features), placed over the radiometry layer (its scale and translate), and a
one-line summary shows the pitch, rotation, RMS residual and flagged lenslets.

"Save calibration..." writes the calibration file atomically (JSON plus the dark frame
beside it); an existing file is replaced only after the user agrees. The saved path becomes
the overlay layers' ``source`` and fills the calibration field of every open Reconstruct
widget of the same viewer. Bad input (no grid, saturated frame, wrong design, mismatched
dark frame) is an error notification with the engine's message, and no layer is added.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import napari
import numpy as np
from napari.layers import Layer
from qtpy.QtWidgets import (
    QApplication,
    QCheckBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QMessageBox,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.calibration import Calibration, calibrate, save_calibration
from lfm_studio.engine.calibration.calibration_io import calibration_files
from lfm_studio.engine.design import Design
from lfm_studio.napari_plugin.background import BackgroundTask, Outcome
from lfm_studio.napari_plugin.calibration_reader import overlay_layer_data
from lfm_studio.napari_plugin.design_source import DesignSource
from lfm_studio.napari_plugin.layer_picker import LayerPicker, unwrapped
from lfm_studio.napari_plugin.notify import report_error, report_info
from lfm_studio.napari_plugin.reconstruct_widget import ReconstructWidget, is_camera_image
from lfm_studio.napari_plugin.task_controls import TaskControls


def summary_line(calibration: Calibration) -> str:
    """One line on a calibration: pitch (px), rotation (deg), RMS residual (px) and flagged lenslets."""
    summary = calibration.summary()
    if calibration.grid is not None:  # a lenslet lattice (conventional LFM), else Fourier sub-images
        py, px = summary["pitch_yx_px"]
        return (
            f"pitch {py:.4f} x {px:.4f} px, rotation {summary['rotation_deg']:.4f} deg, "
            f"RMS residual {summary['rms_residual_px']:.4f} px, "
            f"{summary['flagged']} of {summary['lenslets']} lenslets flagged"
        )
    return (
        f"scale {summary['scale']:.5f}, rotation {summary['rotation_deg']:.4f} deg, "
        f"RMS residual {summary['rms_residual_px']:.4f} px, "
        f"{summary['flagged']} of {summary['sub_images']} sub-images flagged"
    )


def _frame(layer: Any) -> np.ndarray:
    """A float64 copy of a 2-D image layer's data (the worker thread never touches the layer)."""
    return np.array(layer.data, dtype=np.float64, copy=True)


class CalibrateWidget(QWidget):
    """The "Calibrate" dock widget of ``napari_viewer``."""

    def __init__(self, napari_viewer: napari.viewer.Viewer, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.viewer = napari_viewer
        self.design: Design | None = None
        self.calibration: Calibration | None = None
        self.overlay: list[Any] = []
        self.radiometry_picker = LayerPicker(napari_viewer, is_camera_image)
        self.use_dark = QCheckBox("subtract")
        self.dark_picker = LayerPicker(napari_viewer, is_camera_image)
        self.source = DesignSource(self.set_design)
        self.preset, self.browse = self.source.preset, self.source.file_button
        self.design_label = QLabel("")
        self.design_label.setWordWrap(True)
        self.controls = TaskControls("Calibrate")
        self.summary = QLabel("no calibration yet")
        self.summary.setWordWrap(True)
        self.save_button = QPushButton("Save calibration...")
        self.save_button.setEnabled(False)
        dark = QHBoxLayout()
        dark.addWidget(self.use_dark)
        dark.addWidget(self.dark_picker, 1)
        form = QFormLayout()
        form.addRow("Radiometry", self.radiometry_picker)
        form.addRow("Dark frame", dark)
        form.addRow("Design", self.source)
        form.addRow("", self.design_label)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(self.controls)
        layout.addWidget(self.summary)
        layout.addWidget(self.save_button)
        layout.addStretch(1)
        self.use_dark.toggled.connect(self.dark_picker.setEnabled)
        self.dark_picker.setEnabled(False)
        self.controls.runClicked.connect(self.start)
        self.save_button.clicked.connect(self._save_clicked)
        self._task: BackgroundTask | None = None
        self._placement: dict[str, Any] = {}
        self._name = ""
        self.source.choose_first()

    # ----- the contract (buttons call these; so can tests and scripts) -----

    @property
    def busy(self) -> bool:
        """Whether a calibration is running."""
        return self._task is not None

    def set_design(self, design: Design, label: str | None = None) -> None:
        """Calibrate against the nominal ``design`` next."""
        self.design = design
        ny, nx = design.camera.pixel_count
        self.design_label.setText(
            f"{label or design.name}: {design.kind} LFM, {ny} x {nx} px camera, {design.mla.count} lenslets"
        )

    def set_preset(self, name: str) -> bool:
        """Use the bundled preset ``name``; False (with an error notification) if it cannot be read."""
        return self.source.set_preset(name)

    def load_design_file(self, path: str | Path) -> bool:
        """Use the design file ``path``; False (with an error notification) if it cannot be read."""
        return self.source.load_design_file(path)

    def set_dark(self, layer: Any | None) -> None:
        """Subtract the dark image ``layer`` (None: no dark frame, the design's camera baseline is used)."""
        self.use_dark.setChecked(layer is not None)
        if layer is not None:
            self.dark_picker.set_layer(layer)

    def start(self) -> bool:
        """Start the calibration; False (with an error notification) when the input is refused."""
        if self._task is not None:
            return False
        radiometry = self.radiometry_picker.layer()
        dark = self.dark_picker.layer() if self.use_dark.isChecked() else None
        problem = None
        if self.design is None:
            problem = "no design chosen. Fix: pick a preset or a design file."
        elif radiometry is None:
            problem = (
                "no radiometry image. Fix: open the radiometry frame (a uniform slide) as a 2D image layer."
            )
        elif self.use_dark.isChecked() and dark is None:
            problem = "no dark image layer. Fix: open the dark frame, or untick 'subtract'."
        if problem is not None:
            report_error(f"Cannot calibrate: {problem}")
            return False
        design, frame = self.design, _frame(radiometry)
        dark_frame = None if dark is None else _frame(dark)
        self._name = radiometry.name
        self._placement = {"scale": tuple(radiometry.scale), "translate": tuple(radiometry.translate)}

        def compute(progress: Any, cancel: Any) -> Calibration:
            return calibrate(frame, design, dark=dark_frame, progress=progress, cancel=cancel)

        self._task = BackgroundTask(compute, self)
        self._task.ended.connect(self._on_ended)
        self.controls.attach(self._task, f"calibrating {radiometry.name!r} against {design.name!r}")
        self._task.start()
        return True

    def cancel(self) -> None:
        """Stop the running calibration (no layer is added)."""
        self.controls.cancel()

    def save(self, path: str | Path, *, overwrite: bool = False) -> Path | None:
        """Save the last calibration to ``path`` (atomic); None (with an error notification) when refused.

        An existing file (or its dark-frame file) is kept unless ``overwrite``. On success the
        overlay layers take ``path`` as their source and open Reconstruct widgets use it.
        """
        if self.calibration is None:
            report_error("Nothing to save: no calibration yet. Fix: run Calibrate first.")
            return None
        try:
            saved = save_calibration(self.calibration, path, overwrite=overwrite)
        except (OSError, ValueError) as error:
            report_error(f"Calibration not saved: {error}")
            return None
        for layer in self.overlay:
            layer.metadata = {**layer.metadata, "source": str(saved)}
        for widget in self._reconstruct_widgets():
            widget.set_calibration(saved)
        report_info(f"Calibration saved to {saved}")
        return saved

    # ----- internals -----

    def _save_clicked(self) -> None:
        path, _ = QFileDialog.getSaveFileName(
            self,
            "Save calibration",
            f"{self._name or 'calibration'}.json",
            "Calibration (*.json)",
            options=QFileDialog.Option.DontConfirmOverwrite,  # asked below, dark-frame file included
        )
        if not path:
            return
        existing = calibration_files(path)  # the JSON and the dark frame it names
        overwrite = False
        if existing:
            names = ", ".join(p.name for p in existing)
            answer = QMessageBox.question(
                self, "Replace calibration?", f"{names} already exists. Replace it?"
            )
            if answer != QMessageBox.StandardButton.Yes:
                return
            overwrite = True
        self.save(path, overwrite=overwrite)

    def _reconstruct_widgets(self) -> list[ReconstructWidget]:
        """The open Reconstruct widgets of this viewer."""
        viewer = unwrapped(self.viewer)
        return [
            widget
            for widget in QApplication.allWidgets()
            if isinstance(widget, ReconstructWidget) and unwrapped(widget.viewer) is viewer
        ]

    def _on_ended(self, outcome: Outcome) -> None:
        self._task = None
        if outcome.state == "cancelled":
            report_info("Calibration cancelled; no layer was added.")
        elif outcome.state == "failed":
            report_error(f"Calibration failed: {outcome.message}")
        elif outcome.state == "done":
            self._show(outcome.value)

    def _show(self, calibration: Calibration) -> None:
        """Add the overlay layers (all made before any is added) and the summary line."""
        layers = [
            Layer.create(data, {**meta, **self._placement}, kind)
            for data, meta, kind in overlay_layer_data(calibration, name=self._name)
        ]
        self.calibration = calibration
        self.overlay = [self.viewer.add_layer(layer) for layer in layers]
        self.summary.setText(summary_line(calibration))
        self.save_button.setEnabled(True)
