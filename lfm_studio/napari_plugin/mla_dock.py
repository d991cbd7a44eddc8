"""Dock widget "MLA editor": edit a design's lenslets inside napari, save the design, recompute its PSF.

The studio's :class:`~lfm_studio.widgets.mla_editor.MLAEditor` on the lenslets of a preset,
a design file, or the design recorded in the selected PSF layer. Each committed edit
(drag, add, delete, resize, table edit, undo) becomes a new validated design; a refused
one is an error notification with the design's reason and keeps the last valid design.
*Save design...* writes it atomically (the file dialog asks before replacing a file;
:meth:`MLADock.save_design_as` refuses to replace unless told to). *Recompute PSF*
computes the edited design's PSF stack in the background (progress, Cancel) and
replaces the PSF layer the design came from, or adds a new layer. Regular arrays
(conventional LFM) are edited by pitch in the design file, not here.
"""

from __future__ import annotations

import weakref
from pathlib import Path
from typing import Any

import napari
from napari.layers import Layer
from qtpy.QtWidgets import QFileDialog, QLabel, QPushButton, QVBoxLayout, QWidget

from lfm_studio.engine.design import Design, MLASpec, save_design
from lfm_studio.engine.errors import error_text
from lfm_studio.napari_plugin.background import BackgroundTask, Outcome
from lfm_studio.napari_plugin.design_source import DesignSource
from lfm_studio.napari_plugin.layer_data import LayerError, design_of, kind_of, psf_layer_data
from lfm_studio.napari_plugin.layer_picker import same_layer, unwrapped
from lfm_studio.napari_plugin.notify import (
    design_warnings_collected,
    report_error,
    report_info,
)
from lfm_studio.napari_plugin.psf_task import start_psf_task
from lfm_studio.napari_plugin.task_controls import TaskControls
from lfm_studio.widgets.mla_editor import MLAEditor


class MLADock(QWidget):
    """The "MLA editor" dock widget of ``napari_viewer``."""

    def __init__(self, napari_viewer: napari.viewer.Viewer, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.viewer = napari_viewer
        self.design: Design | None = None
        self.source = DesignSource(self._design_chosen, refusal="edit", file_button="Open...")
        self.preset, self.open_file = self.source.preset, self.source.file_button
        self.from_layer = QPushButton("From PSF layer")
        self.from_layer.setToolTip("Edit the design recorded in the selected PSF layer.")
        self.editor = MLAEditor()
        self.status = QLabel("")
        self.status.setWordWrap(True)
        self.save_button = QPushButton("Save design...")
        self.controls = TaskControls("Recompute PSF")
        self.source.row.insertWidget(1, self.from_layer)  # preset | From PSF layer | Open...
        layout = QVBoxLayout(self)
        layout.addWidget(self.source)
        layout.addWidget(self.editor, 1)
        layout.addWidget(self.status)
        layout.addWidget(self.save_button)
        layout.addWidget(self.controls)
        self.from_layer.clicked.connect(self.use_selected_layer)
        self.save_button.clicked.connect(self._save_dialog)
        self.editor.lensletsCommitted.connect(self._on_committed)
        self.controls.runClicked.connect(self.recompute)
        self._layer: weakref.ReferenceType[Any] | None = None  # the PSF layer the design came from
        self._task: BackgroundTask | None = None
        self.source.choose_first()

    # ----- choosing the design -----

    @property
    def busy(self) -> bool:
        return self._task is not None

    def set_design(self, design: Design, *, layer: Any = None) -> None:
        """Edit ``design`` (``layer``: the PSF layer it came from, replaced by :meth:`recompute`)."""
        self.design = design
        self._layer = None if layer is None else weakref.ref(unwrapped(layer))
        editable = isinstance(design.mla, MLASpec)
        self.editor.setEnabled(editable)
        if design.pupil_diameter_at_mla is not None:
            self.editor.set_pupil_radius(design.pupil_diameter_at_mla / 2.0 * 1e6)
        width, height = design.camera.sensor_size
        radius = design.sub_image_radius
        self.editor.set_sensor(
            (width * 1e6, height * 1e6),
            0.0 if radius is None else radius * 1e6,
            pixel_pitch_um=design.camera.pixel_pitch_um,
        )
        self.editor.set_lenslets(design.mla.lenslets if editable else (), reset_history=True)
        self.editor.fit()
        origin = f" (from layer {layer.name!r})" if layer is not None else ""
        note = "" if editable else " A regular lenslet grid: edit its pitch in the design file."
        self.status.setText(f"{design.name}{origin}: {design.mla.count} lenslets.{note}")

    def set_preset(self, name: str) -> bool:
        """Edit the bundled preset ``name``."""
        return self.source.set_preset(name)

    def load_design_file(self, path: str | Path) -> bool:
        """Edit the design in file ``path``."""
        return self.source.load_design_file(path)

    def use_selected_layer(self) -> bool:
        """Edit the design of the selected PSF layer; False (with an error notification) if there is none."""
        layer = self.viewer.layers.selection.active
        if layer is None or kind_of(layer.metadata) != "psf_stack":
            report_error("Select a PSF stack layer first (one computed by lfm_studio records its design).")
            return False
        try:
            design = design_of(layer.metadata, layer.name)
        except LayerError as error:
            report_error(str(error))
            return False
        if not isinstance(design, Design):
            report_error(f"Layer {layer.name!r} records no lfm_studio design (a measured PSF?).")
            return False
        self.set_design(design, layer=layer)
        return True

    # ----- saving and recomputing -----

    def save_design_as(self, path: str | Path, *, overwrite: bool = False) -> bool:
        """Save the edited design to ``path`` atomically; an existing file is replaced only with ``overwrite``."""
        if self.design is None:
            report_error("No design to save. Fix: pick a preset, a design file or a PSF layer.")
            return False
        try:
            written = save_design(self.design, path, overwrite=overwrite)
        except (OSError, ValueError) as error:
            report_error(f"Design not saved: {error}")
            return False
        report_info(f"Saved the design to {written}.")
        return True

    def recompute(self) -> bool:
        """Compute the edited design's PSF in the background; replace the source layer or add one when done."""
        if self.design is None or self._task is not None:
            return False
        self._task = start_psf_task(
            self.design, parent=self, controls=self.controls, on_ended=self._on_ended,
            message=f"computing the PSF of {self.design.name!r}",
        )  # fmt: skip
        return True

    def cancel(self) -> None:
        """Stop the running PSF computation (layers stay as they were)."""
        self.controls.cancel()

    # ----- internals -----

    def _design_chosen(self, design: Design, label: str) -> None:
        self.set_design(design)

    def _save_dialog(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Save the design", "", "Design files (*.json)")
        if path:  # the dialog has asked before replacing an existing file
            self.save_design_as(path, overwrite=True)

    def _on_committed(self, lenslets: Any) -> None:
        if self.design is None or not isinstance(self.design.mla, MLASpec):
            return
        try:
            with design_warnings_collected():
                mla = {**self.design.mla.model_dump(), "lenslets": tuple(lenslets)}
                design = self.design.updated(mla=mla)
        except ValueError as error:
            report_error(f"Lenslet edit not applied to the design: {error_text(error)}")
            self.status.setText(f"Refused: {error_text(error)}")
            return
        self.design = design
        self.status.setText(f"{design.name}: {design.mla.count} lenslets (edited; not saved).")

    def _source_layer(self) -> Any | None:
        """The PSF layer the design came from, if it is still in the viewer."""
        target = self._layer() if self._layer is not None else None
        return next((layer for layer in self.viewer.layers if same_layer(layer, target)), None)

    def _on_ended(self, outcome: Outcome) -> None:
        self._task = None
        if outcome.state == "cancelled":
            report_info("PSF computation cancelled; layers are unchanged.")
            return
        if outcome.state == "failed":
            report_error(f"PSF computation failed: {outcome.message}")
            return
        layer = self._source_layer()
        name = layer.name if layer is not None else f"PSF {outcome.value.design.name}"
        data, meta, _ = psf_layer_data(outcome.value, name=name)
        if layer is None:
            self.viewer.add_layer(Layer.create(data, meta, "image"))
            return
        layer.metadata = meta["metadata"]
        layer.data = data
        layer.scale, layer.translate = meta["scale"], meta["translate"]
        layer.reset_contrast_limits()
