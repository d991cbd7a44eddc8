"""Dock widget "Reconstruct light field": image layer + PSF layer -> volume layer, in the background.

Pick the camera image and the PSF stack layers, the method (the engine's registry:
Richardson-Lucy, its accelerated form, Wiener, Tikhonov, and any method registered later) and
its options (iterations, background, SNR, ...; the fields of other methods are disabled). Camera counts become
photons from the image's camera metadata (an image without it gets an estimated
baseline, said in a warning notification), so the volume is in photons per voxel.
Inputs are checked
before anything starts (a mismatch, e.g. of pixel sizes, is an error notification
naming both layers and values); the reconstruction then runs as a
background job (:mod:`lfm_studio.widgets.jobs`) with progress and Cancel. Only a finished reconstruction adds a
layer: the volume in object space (voxel size from the PSF's magnification and depth
step, in um), its settings in the layer metadata. The view is then fitted to that layer
(:func:`fit_view_to`): object-space volumes are about 30 times smaller than the camera-space
image and PSF layers, and napari's own reset (the Home button) fits them all. Cancel or failure
adds nothing and leaves every layer and the view as they were.

A raw camera frame (the lenslet grid at some offset, rotation and non-integer pitch) is
reconstructed with an optional calibration file from ``lfm-studio calibrate``: the frame is
dark-subtracted, defect-corrected, flat-fielded and rectified onto the PSF's lattice first,
and the camera baseline is then 0 (the dark level is the calibration's). The field defaults
to the calibration whose grid overlay was opened last (the lfm-studio reader).
"""

from __future__ import annotations

import inspect
from functools import partial
from pathlib import Path
from typing import Any

import napari
import numpy as np
from napari.layers import Image, Layer
from qtpy.QtWidgets import (
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLineEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.calibration import CalibrationFileError, load_calibration
from lfm_studio.engine.errors import error_text
from lfm_studio.engine.systems.kinds import CONVENTIONAL, FOURIER, SystemKind
from lfm_studio.napari_plugin import reconstruction
from lfm_studio.napari_plugin.background import BackgroundTask, Outcome
from lfm_studio.napari_plugin.calibration_reader import calibration_source
from lfm_studio.napari_plugin.layer_data import (
    LayerError,
    image_from_layer,
    kind_of,
    stack_from_layer,
    volume_layer_data,
)
from lfm_studio.napari_plugin.layer_picker import LayerPicker
from lfm_studio.napari_plugin.notify import report_error, report_info, report_warning
from lfm_studio.napari_plugin.task_controls import TaskControls
from lfm_studio.widgets.method_options import MethodOptions


def is_camera_image(layer: Any) -> bool:
    """A 2-D grayscale image layer that is not a PSF stack or a volume of ours."""
    return (
        isinstance(layer, Image)
        and not layer.rgb
        and layer.ndim == 2
        and kind_of(layer.metadata) in (None, "light_field")
    )


def psf_layer_kind(layer: Any) -> SystemKind:
    """The kind whose projector a PSF layer feeds: 5-D ``(S, S, Z, H, H)`` lenslet patterns are a
    lenslet-lattice stack, 3-D ``(Z, Y, X)`` per-depth PSFs shift-invariant (:func:`psf_layer_data`)."""
    return CONVENTIONAL if np.ndim(layer.data) == 5 else FOURIER


def is_psf_stack(layer: Any) -> bool:
    return isinstance(layer, Image) and kind_of(layer.metadata) == "psf_stack"


def _is_ours(layer: Any) -> int:
    return int(kind_of(layer.metadata) is not None)


def fit_view_to(viewer: napari.viewer.Viewer, layer: Layer) -> bool:
    """Pan and zoom the canvas onto ``layer`` (camera angles kept) with napari's
    ``fit_to_view(layers=...)``; False, the view unchanged, where that cannot be done: a napari
    without it, or a viewer with more dimensions than ``layer`` (e.g. a 5-D conventional pattern
    stack beside the 3-D volume), where napari 0.9.2 indexes the viewer's displayed axes into the
    layer's extent and raises ``IndexError``."""
    fit = getattr(viewer, "fit_to_view", None)
    if fit is None or "layers" not in inspect.signature(fit).parameters or layer.ndim != viewer.dims.ndim:
        return False
    fit(layers=[layer])
    return True


class ReconstructWidget(QWidget):
    """The "Reconstruct light field" dock widget of ``napari_viewer``."""

    def __init__(self, napari_viewer: napari.viewer.Viewer, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.viewer = napari_viewer
        self.image_picker = LayerPicker(napari_viewer, is_camera_image, preferred=_is_ours)
        self.psf_picker = LayerPicker(napari_viewer, is_psf_stack)
        self.options = MethodOptions()  # method box + option fields, from the engine's registry
        self.method = self.options.method
        self.background = self.options.field("background")
        self.background.setToolTip(
            "Extra background per pixel in photons (e.g. out-of-focus light), modelled by RL. The camera "
            "baseline is removed first, from the image's camera metadata (or estimated, with a warning)."
        )
        self.calibration = QLineEdit()
        self.calibration.setPlaceholderText("none: the image is already on the PSF's lattice")
        self.calibration.setToolTip(
            "Calibration JSON from 'lfm-studio calibrate' for a raw camera frame: dark frame, hot pixels, "
            "flat field and rectification onto the PSF's lattice are applied before reconstructing."
        )
        browse = QPushButton("Browse...")
        browse.clicked.connect(self._browse_calibration)
        calibration_row = QHBoxLayout()
        calibration_row.addWidget(self.calibration, 1)
        calibration_row.addWidget(browse)
        self.controls = TaskControls("Reconstruct")
        form = QFormLayout()
        form.addRow("Light-field image", self.image_picker)
        form.addRow("PSF stack", self.psf_picker)
        form.addRow("Calibration (raw frame)", calibration_row)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addWidget(self.options)
        layout.addWidget(self.controls)
        layout.addStretch(1)
        self.controls.runClicked.connect(self.start)
        self.psf_picker.currentIndexChanged.connect(self._offer_methods_for_psf)
        self._offer_methods_for_psf()
        self._task: BackgroundTask | None = None
        self._request: reconstruction.Request | None = None
        napari_viewer.layers.events.inserted.connect(self._on_layer_inserted)
        for layer in napari_viewer.layers:
            self._on_layer_inserted(layer=layer)

    # ----- the contract (buttons call these; so can tests and scripts) -----

    @property
    def busy(self) -> bool:
        """Whether a reconstruction is running."""
        return self._task is not None

    def option_field(self, name: str) -> QWidget:
        """The field of the method option ``name`` (``"iterations"``, ``"snr"``, ...)."""
        return self.options.field(name)

    @property
    def iterations(self) -> QWidget:
        return self.options.field("iterations")

    @property
    def snr(self) -> QWidget:
        return self.options.field("snr")

    def set_method(self, method: str) -> None:
        """Choose a registered ``method`` by name (``"rl"``, ``"rl-accelerated"``, ``"wiener"``, ...)."""
        self.options.set_method(method)

    def set_calibration(self, path: str | Path | None) -> None:
        """Reconstruct the image as a raw frame with the calibration file ``path`` (None: no calibration)."""
        self.calibration.setText("" if path is None else str(path))

    def settings(self) -> reconstruction.Settings:
        """The settings shown (raises ``ValueError`` for invalid ones)."""
        return reconstruction.Settings(method=self.options.method_name(), options=self.options.values())

    def start(self) -> bool:
        """Check the inputs and start the reconstruction; False (with an error notification) if refused."""
        if self._task is not None:
            return False
        try:
            request = self._request_from_layers()
        except ValueError as error:
            report_error(error_text(error))
            return False
        self._request = request
        task = BackgroundTask(partial(reconstruction.run, request), self)
        task.ended.connect(self._on_ended)
        self.controls.attach(task, f"reconstructing {request.image_name!r}")
        self._task = task
        task.start()
        return True

    def cancel(self) -> None:
        """Stop the running reconstruction before its next iteration (no layer is added)."""
        self.controls.cancel()

    # ----- internals -----

    def _request_from_layers(self) -> reconstruction.Request:
        image_layer, psf_layer = self.image_picker.layer(), self.psf_picker.layer()
        if image_layer is None:
            raise LayerError(
                "No light-field image to reconstruct. Fix: open a camera image (a 2-D image layer), or "
                "File > Open Sample > lfm-studio > Bead light field."
            )
        if psf_layer is None:
            raise LayerError(
                "No PSF stack layer. Fix: open a PSF TIFF with the lfm-studio reader, or compute one with "
                "the Simulate PSF widget."
            )
        stack = stack_from_layer(psf_layer.data, psf_layer.metadata, name=psf_layer.name)
        image = image_from_layer(
            image_layer.data, image_layer.metadata, image_layer.scale, name=image_layer.name
        )
        calibration, calibration_name = self._calibration()
        return reconstruction.prepare(
            stack,
            image,
            self.settings(),
            image_name=image_layer.name,
            psf_name=psf_layer.name,
            calibration=calibration,
            calibration_name=calibration_name,
        )

    def _calibration(self) -> tuple[Any, str | None]:
        """The calibration of the path field (None, None when empty); a bad file is a ValueError."""
        text = self.calibration.text().strip()
        if not text:
            return None, None
        path = Path(text).expanduser()
        if not path.is_file():
            raise ValueError(
                f"Calibration file {text!r} does not exist. Fix: give the .json written by "
                "'lfm-studio calibrate', or clear the field for an image already on the PSF's lattice."
            )
        try:
            return load_calibration(path), path.name
        except (CalibrationFileError, OSError, KeyError, TypeError) as error:
            raise ValueError(f"Calibration file {path.name} cannot be used: {error}") from error

    def _browse_calibration(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Calibration file", "", "Calibration (*.json)")
        if path:
            self.set_calibration(path)

    def _offer_methods_for_psf(self, *_: Any) -> None:
        """Offer the methods that take the chosen PSF layer's kind (a 5-D conventional pattern stack
        disables Wiener, with the reason in its tooltip; the studio does the same per design)."""
        layer = self.psf_picker.layer()
        if layer is not None:
            self.options.restrict_to_kind(psf_layer_kind(layer))

    def _on_layer_inserted(self, event: Any = None, *, layer: Any = None) -> None:
        """A calibration overlay opened by the reader fills the calibration field."""
        layer = event.value if layer is None else layer
        source = calibration_source(layer)
        if source is not None:
            self.set_calibration(source)

    def _on_ended(self, outcome: Outcome) -> None:
        request, self._task, self._request = self._request, None, None
        if outcome.state == "done" and request is not None:
            name = f"{request.image_name} {request.settings.method}"
            for note in outcome.value.metadata.get("notes", []):
                report_warning(f"{request.image_name}: {note}")
            layer = self.viewer.add_layer(Layer.create(*volume_layer_data(outcome.value, name=name)))
            fit_view_to(self.viewer, layer)
        elif outcome.state == "cancelled":
            report_info("Reconstruction cancelled; no layer was added.")
        elif outcome.state == "failed":
            report_error(f"Reconstruction failed: {outcome.message}")
