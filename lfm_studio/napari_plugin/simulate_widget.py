"""Dock widget "Simulate PSF": a preset or design file -> a PSF stack layer, in the background.

Choose a bundled preset or a design file, optionally other depths (start, stop, step
in um) and an accuracy preset, then Simulate: the PSF stack is computed as a
:class:`~lfm_studio.napari_plugin.background.BackgroundTask` (a job of
:class:`lfm_studio.widgets.jobs.JobRunner`) with progress and Cancel (cancel stops between
depths / lenslets and adds nothing). The layer is at the sensor pixel pitch with the design in its metadata.
An invalid design, file or depth range is an error notification with the engine's
message; design warnings become warning notifications.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import napari
from napari.layers import Layer
from qtpy.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.design import AccuracySpec, DepthSpec, Design
from lfm_studio.engine.design.errors import fmt
from lfm_studio.engine.errors import error_text
from lfm_studio.napari_plugin.background import BackgroundTask, Outcome
from lfm_studio.napari_plugin.design_source import DesignSource
from lfm_studio.napari_plugin.layer_data import psf_layer_data
from lfm_studio.napari_plugin.notify import (
    design_warnings_collected,
    report_error,
    report_info,
)
from lfm_studio.napari_plugin.psf_task import start_psf_task
from lfm_studio.napari_plugin.task_controls import TaskControls

DESIGN_ACCURACY = "as in the design"
ACCURACIES = (DESIGN_ACCURACY, "preview", "standard", "reference")
DEPTH_LIMIT_UM = 1e5


def _depth_box(suffix: str = " um") -> QDoubleSpinBox:
    box = QDoubleSpinBox()
    box.setRange(-DEPTH_LIMIT_UM, DEPTH_LIMIT_UM)
    box.setDecimals(3)
    box.setSuffix(suffix)
    return box


def describe(design: Design, depths: str | None = None) -> str:
    """One line on what a PSF of ``design`` costs: kind, camera pixels, depths (``depths``: other
    words for them, e.g. the widget's own depths), lenslets."""
    ny, nx = design.camera.pixel_count
    depths = depths or f"{design.depths.count} depths"
    return f"{design.kind} LFM, {ny} x {nx} px camera, {depths}, {design.mla.count} lenslets"


def describe_depths(start_um: float, stop_um: float, step_um: float) -> str:
    """The depths ``start:stop:step`` um in words (``"3 depths, -10 to 10 um"``), or why they are refused."""
    try:
        spec = DepthSpec(depth_range_um=(start_um, stop_um), depth_step_um=step_um)
    except ValueError as error:
        return f"other depths refused ({error_text(error)})"
    values = spec.values_um
    return f"{spec.count} depths, {fmt(values[0])} to {fmt(values[-1])} um"


class SimulateWidget(QWidget):
    """The "Simulate PSF" dock widget of ``napari_viewer``."""

    def __init__(self, napari_viewer: napari.viewer.Viewer, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.viewer = napari_viewer
        self.design: Design | None = None
        self._label = ""
        self.source = DesignSource(self.set_design)
        self.preset, self.browse = self.source.preset, self.source.file_button
        self.summary = QLabel("")
        self.summary.setWordWrap(True)
        self.custom_depths = QCheckBox("other depths")
        self.depth_start, self.depth_stop, self.depth_step = _depth_box(), _depth_box(), _depth_box()
        self.depth_step.setMinimum(1e-3)
        self.accuracy = QComboBox()
        self.accuracy.addItems(ACCURACIES)
        self.controls = TaskControls("Simulate")
        depths = QHBoxLayout()
        for box in (self.depth_start, self.depth_stop, self.depth_step):
            depths.addWidget(box)
        form = QFormLayout()
        form.addRow("Design", self.source)
        form.addRow("", self.summary)
        form.addRow("Depths", self.custom_depths)
        form.addRow("start, stop, step", depths)
        form.addRow("Accuracy", self.accuracy)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(self.controls)
        layout.addStretch(1)
        self.custom_depths.toggled.connect(self._on_custom_depths)
        for box in (self.depth_start, self.depth_stop, self.depth_step):
            box.valueChanged.connect(self._show_summary)
        self.controls.runClicked.connect(self.start)
        self._task: BackgroundTask | None = None
        self._name = ""
        self._on_custom_depths(False)
        self.source.choose_first()

    # ----- the contract -----

    @property
    def busy(self) -> bool:
        return self._task is not None

    def set_design(self, design: Design, label: str | None = None) -> None:
        """Simulate ``design`` next; its depths fill the depth fields."""
        self.design, self._label = design, label or design.name
        start, stop = design.depths.depth_range_um
        for box, value in zip(
            (self.depth_start, self.depth_stop, self.depth_step),
            (start, stop, design.depths.depth_step_um),
            strict=True,
        ):
            box.setValue(value)
        self._show_summary()

    def set_preset(self, name: str) -> bool:
        """Use the bundled preset ``name``; False (with an error notification) if it cannot be read."""
        return self.source.set_preset(name)

    def load_design_file(self, path: str | Path) -> bool:
        """Use the design file ``path``; False (with an error notification) if it cannot be read."""
        return self.source.load_design_file(path)

    def set_depths_um(self, start: float, stop: float, step: float) -> None:
        """Simulate at ``start:stop:step`` um instead of the design's depths."""
        self.custom_depths.setChecked(True)
        for box, value in zip(
            (self.depth_start, self.depth_stop, self.depth_step), (start, stop, step), strict=True
        ):
            box.setValue(value)

    def set_accuracy(self, name: str) -> None:
        """``"preview"``, ``"standard"``, ``"reference"`` or :data:`DESIGN_ACCURACY`."""
        index = self.accuracy.findText(name)
        if index < 0:
            raise ValueError(f"accuracy must be one of {', '.join(ACCURACIES)}; got {name!r}.")
        self.accuracy.setCurrentIndex(index)

    def design_to_simulate(self) -> Design:
        """The chosen design with the depth and accuracy choices applied (raises ``ValueError`` if invalid)."""
        if self.design is None:
            raise ValueError("No design chosen. Fix: pick a preset or a design file.")
        changes: dict[str, Any] = {}
        if self.custom_depths.isChecked():
            changes["depths"] = {
                "depth_range_um": (self.depth_start.value(), self.depth_stop.value()),
                "depth_step_um": self.depth_step.value(),
            }
        if self.accuracy.currentText() != DESIGN_ACCURACY:
            changes["accuracy"] = AccuracySpec.from_preset(self.accuracy.currentText())
        if not changes:
            return self.design
        with design_warnings_collected():
            return self.design.updated(**changes)

    def start(self) -> bool:
        """Start the PSF computation; False (with an error notification) if the design is refused."""
        if self._task is not None:
            return False
        try:
            design = self.design_to_simulate()
        except ValueError as error:
            report_error(f"Cannot simulate: {error_text(error)}")
            return False
        self._name = f"PSF {design.name}"
        self._task = start_psf_task(
            design, parent=self, controls=self.controls, on_ended=self._on_ended,
            message=f"simulating {design.name!r}: {describe(design)}",
        )  # fmt: skip
        return True

    def cancel(self) -> None:
        """Stop the running simulation (no layer is added)."""
        self.controls.cancel()

    # ----- internals -----

    def _on_custom_depths(self, checked: bool) -> None:
        for box in (self.depth_start, self.depth_stop, self.depth_step):
            box.setEnabled(checked)
        self._show_summary()

    def _show_summary(self) -> None:
        """The design line, with the depths that will be simulated (the design's or the other depths)."""
        if self.design is None:
            return
        depths = None
        if self.custom_depths.isChecked():
            depths = describe_depths(
                self.depth_start.value(), self.depth_stop.value(), self.depth_step.value()
            )
        self.summary.setText(f"{self._label}: {describe(self.design, depths)}")

    def _on_ended(self, outcome: Outcome) -> None:
        self._task = None
        if outcome.state == "done":
            self.viewer.add_layer(Layer.create(*psf_layer_data(outcome.value, name=self._name)))
        elif outcome.state == "cancelled":
            report_info("PSF simulation cancelled; no layer was added.")
        elif outcome.state == "failed":
            report_error(f"PSF simulation failed: {outcome.message}")
