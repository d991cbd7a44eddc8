"""``PSFViewer``: the PSF stack, the camera image and the reconstruction as layers in micrometres.

napari (embedded through :mod:`lfm_studio.widgets.viewer.napari_embed`) when OpenGL works, otherwise a
pyqtgraph fallback (:mod:`lfm_studio.widgets.viewer.pyqtgraph_volume`) with a message saying why.

Display conventions (sensor / sample micrometres, depth stretch, max-pooled pyramid) are
those of :mod:`lfm_studio.widgets.viewer.display_data`. The two spaces do not share a world: each
has its own napari canvas, and showing a layer of the other space switches canvas (layers
are kept and updated in place, never re-made).

``show_psf`` / ``show_image`` / ``show_volume`` prepare the display data on the calling (GUI)
thread; for large data build it on a worker with ``psf_display`` etc. and pass it to
:meth:`PSFViewer.show_display`, which only hands finished arrays to the canvas.

All methods must be called on the GUI thread.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import torch
from qtpy.QtCore import QThread
from qtpy.QtWidgets import (
    QApplication,
    QComboBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.widgets.stale_mark import StaleMark
from lfm_studio.widgets.viewer import napari_embed
from lfm_studio.widgets.viewer.display_data import (
    DEFAULT_MAX_VOXELS_3D,
    DisplayData,
    describe,
    image_display,
    psf_display,
    volume_display,
)
from lfm_studio.widgets.viewer.napari_scene import NapariScene


class PSFViewer(QWidget):
    """The PSF stack, light-field image and reconstruction as layers with physical scale (um).

    Parameters
    ----------
    parent : QWidget, optional
    use_napari : bool or None
        ``None``: napari when it works here (see
        :func:`~lfm_studio.widgets.viewer.napari_embed.napari_unavailable_reason`), else the pyqtgraph
        fallback with a message saying why; ``True``: napari or ``RuntimeError``; ``False``:
        the fallback.
    max_voxels_3d : int
        Largest 3-D block rendered at full resolution in 3-D (larger: max-pooled preview).

    Notes
    -----
    Call :meth:`close_viewer` when the viewer is no longer needed (a widget inside a main
    window gets no close event of its own); it releases napari's canvas and the layers.
    """

    def __init__(
        self,
        parent: QWidget | None = None,
        *,
        use_napari: bool | None = None,
        max_voxels_3d: int = DEFAULT_MAX_VOXELS_3D,
    ) -> None:
        super().__init__(parent)
        reason = (
            "the 2-D viewer was requested"
            if use_napari is False
            else napari_embed.napari_unavailable_reason()
        )
        if use_napari is True and reason is not None:
            raise RuntimeError(f"use_napari=True but napari cannot run here: {reason}.")
        self._closed = False
        self._budget = max_voxels_3d
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self._message = QLabel()
        self._message.setWordWrap(True)
        self._message.setStyleSheet("QLabel { background: #fff3cd; color: #664d03; padding: 4px; }")
        layout.addWidget(self._message)
        layout.addLayout(self._build_toolbar())
        self._info = QLabel("")
        self._info.setStyleSheet("QLabel { color: gray; }")
        layout.addWidget(self._info)
        self._stale_marks: dict[str, StaleMark] = {}
        self._stale = QLabel()  # over the view: the shown layer no longer matches the design
        self._stale.setObjectName("staleBanner")
        self._stale.setWordWrap(True)
        self._stale.setVisible(False)
        layout.addWidget(self._stale)
        if reason is None:
            try:
                self._scene = NapariScene()
            except Exception as exc:  # a canvas that fails to start must not take the studio down
                if use_napari:
                    raise
                reason = f"napari failed to start ({type(exc).__name__}: {exc})"
        self._reason = reason
        self._message.setText(f"3-D viewer unavailable: {reason}. Showing 2-D slices and projections.")
        self._message.setVisible(reason is not None)
        if reason is None:
            self._body = self._build_napari_body()
        else:
            from lfm_studio.widgets.viewer.pyqtgraph_volume import PyqtgraphVolume

            self._scene = self._body = PyqtgraphVolume()
            for control in (
                self._button_3d,
                self._button_mip,
                self._plane,
                self._button_ortho,
                self._button_layers,
            ):
                control.setEnabled(False)
                control.setToolTip("needs the napari viewer")
        layout.addWidget(self._body, 1)

    # -- public API -----------------------------------------------------------------------
    @property
    def backend(self) -> str:
        """``"napari"`` or ``"pyqtgraph"``."""
        return "napari" if self._reason is None else "pyqtgraph"

    @property
    def message(self) -> str | None:
        """Why the fallback is shown (``None`` with napari)."""
        return self._message.text() if self._reason is not None else None

    @property
    def stale_text(self) -> str | None:
        """The banner over the view (the shown layer's stale mark), or None when it shows a fresh result."""
        return self._stale.text() if not self._stale.isHidden() else None

    def set_stale_marks(self, marks: dict[str, StaleMark]) -> None:
        """Marks per layer name (e.g. ``{"PSF": StaleMark("stale: shows the previous design; PSF failed: ...", "failed")}``).

        The shown layer's mark appears as a banner over the view; layers not in ``marks`` are fresh.
        """
        self._stale_marks = {
            str(name): mark for name, mark in marks.items() if mark is not None and mark.text
        }
        self._update_stale()

    def show_display(self, shown: DisplayData) -> None:
        """Show prepared display data (built off the GUI thread); updates the layer of its name in place."""
        self._put(shown, "show_display")

    def show_psf(self, stack: PSFStack, *, name: str = "PSF") -> None:
        """Show a PSF stack (camera-side lateral um, sample-side depth um); updates ``name`` in place."""
        self._put(psf_display(stack, name, max_voxels_3d=self._budget), "show_psf")

    def show_image(self, image: torch.Tensor, pixel_size_m: float, name: str = "light field") -> None:
        """Show a camera image ``(..., Y, X)`` with ``pixel_size_m`` metre pixels."""
        self._put(image_display(image, pixel_size_m, name, max_voxels_3d=self._budget), "show_image")

    def show_volume(
        self,
        volume: torch.Tensor,
        voxel_size_m: tuple[float, float, float],
        name: str = "reconstruction",
        *,
        origin_m: tuple[float, float, float] | None = None,
    ) -> None:
        """Show a sample volume ``(..., Z, Y, X)``, voxel ``(dz, dy, dx)`` metres (centred unless ``origin_m``)."""
        self._put(
            volume_display(volume, voxel_size_m, name, origin_m, max_voxels_3d=self._budget), "show_volume"
        )

    def focus(self, name: str) -> None:
        """Show layer ``name`` (and its space) alone."""
        self._require_open("focus")
        if name not in self._scene.names():
            raise KeyError(f"no layer named {name!r}; layers: {self._scene.names()}.")
        self._scene.focus(name)
        self._sync_controls()

    def layer_names(self) -> list[str]:
        return [] if self._closed else self._scene.names()

    def layer(self, name: str) -> Any:
        """The napari ``Image`` layer (napari) or its :class:`DisplayData` (pyqtgraph), or ``None``."""
        return None if self._closed else self._scene.layer(name)

    def clear(self) -> None:
        """Remove every layer."""
        self._require_open("clear")
        self._scene.clear()
        self._sync_controls()

    def set_3d(self, on: bool) -> None:
        """3-D rendering (napari only; the fallback stays 2-D)."""
        self._require_open("set_3d")
        if self.backend == "napari":
            self._scene.set_3d(on)
        self._sync_controls()

    def set_mip(self, on: bool) -> None:
        """Show volumes as their maximum-intensity projection over depth in the 2-D view (napari only)."""
        self._require_open("set_mip")
        if self.backend == "napari":
            self._scene.set_mip(on)
        self._sync_controls()

    def is_mip(self) -> bool:
        return self.backend == "napari" and not self._closed and self._scene.mip

    def is_3d(self) -> bool:
        return self.backend == "napari" and not self._closed and self._scene.model.dims.ndisplay == 3

    def set_plane(self, plane: str) -> None:
        """Slice plane of the 2-D view: ``"xy"``, ``"xz"`` or ``"yz"`` (napari only)."""
        self._require_open("set_plane")
        if self.backend == "napari":
            self._scene.set_plane(plane)
        self._sync_controls(plane=plane)

    def set_orthogonal(self, on: bool) -> None:
        """Show the XZ / YZ maximum projections beside the napari canvas (always shown in the fallback)."""
        self._require_open("set_orthogonal")
        if self.backend == "napari":
            self._ortho.setVisible(on)
            self._update_ortho()
        self._sync_controls()

    def screenshot(self) -> np.ndarray:
        """The rendered canvas (napari) or the widget (fallback) as ``(H, W, 4)`` uint8 RGBA."""
        self._require_open("screenshot")
        return self._scene.screenshot()

    def close_viewer(self) -> None:
        """Release napari's canvas and all layers (idempotent); the widget shows nothing afterwards."""
        if self._closed:
            return
        self._closed = True
        if self.backend == "napari":
            self._scene.depth_changed.disconnect(self._ortho.mark_depth)
            self._scene.close()
        else:
            self._scene.clear()
        self._body.setParent(None)
        self._body.deleteLater()
        self._scene = self._body = None
        self._combo.clear()
        self._info.setText("viewer closed")
        self._update_stale()

    def closeEvent(self, event: Any) -> None:
        self.close_viewer()
        super().closeEvent(event)

    # -- internals ------------------------------------------------------------------------
    def _put(self, shown: DisplayData, what: str) -> None:
        self._require_open(what)
        if not isinstance(shown, DisplayData):
            raise TypeError(
                f"PSFViewer.{what} needs DisplayData (psf_display, ...); got {type(shown).__name__}."
            )
        self._scene.put(shown)
        self._sync_controls()

    def _require_open(self, what: str) -> None:
        app = QApplication.instance()
        if app is None or QThread.currentThread() != app.thread():
            raise RuntimeError(
                f"PSFViewer.{what} must be called on the GUI thread; send results from workers "
                "through a signal (tensors detached and on the CPU)."
            )
        if self._closed:
            raise RuntimeError(f"PSFViewer.{what}: the viewer was closed (close_viewer()).")

    def _update_stale(self) -> None:
        focused = None if self._closed else self._scene.focused
        mark = self._stale_marks.get(focused) if focused is not None else None
        if mark is not None:
            background, colour = mark.colours
            self._stale.setStyleSheet(
                f"QLabel {{ background: {background}; color: {colour}; font-weight: bold; padding: 4px; "
                f"border-left: 6px solid {colour}; }}"
            )
        self._stale.setText(f"{focused}: {mark.text}" if mark is not None else "")
        self._stale.setToolTip("The view shows an out-of-date result; it updates when a fresh one arrives.")
        self._stale.setVisible(mark is not None)
        if self.backend == "napari" and not self._closed:
            self._scene.set_stale_note(mark.short if mark is not None else "")

    def _build_toolbar(self) -> QHBoxLayout:
        bar = QHBoxLayout()
        bar.setContentsMargins(4, 2, 4, 2)
        self._combo = QComboBox()
        self._combo.setToolTip("Layer to show")
        self._combo.setSizeAdjustPolicy(QComboBox.SizeAdjustPolicy.AdjustToContents)  # "reconstruction" whole
        self._combo.currentTextChanged.connect(self._on_combo)
        self._button_3d = _toggle("3D", "Render the stack in 3-D (depth axis may be stretched for display)")
        self._button_3d.toggled.connect(self.set_3d)
        self._button_mip = _toggle(
            "MIP", "Show the maximum-intensity projection over all depths instead of one slice"
        )
        self._button_mip.toggled.connect(self.set_mip)
        self._plane = QComboBox()
        self._plane.addItems(["XY", "XZ", "YZ"])
        self._plane.setToolTip("Slice plane of the 2-D view")
        self._plane.currentTextChanged.connect(self._on_plane)
        self._button_ortho = _toggle("XZ/YZ", "Show XZ and YZ maximum projections")
        self._button_ortho.toggled.connect(self.set_orthogonal)
        self._button_layers = _toggle("Layers", "Show napari's layer list and contrast/colormap controls")
        reset = QPushButton("Reset view")
        reset.clicked.connect(self._on_reset)
        for widget in (
            QLabel("Show:"),
            self._combo,
            self._button_3d,
            self._button_mip,
            QLabel("Plane:"),
            self._plane,
        ):
            bar.addWidget(widget)
        for widget in (self._button_ortho, self._button_layers, reset):
            bar.addWidget(widget)
        bar.addStretch(1)
        return bar

    def _build_napari_body(self) -> QWidget:
        from lfm_studio.widgets.viewer.pyqtgraph_volume import OrthoProjections

        body = QSplitter()
        self._ortho = OrthoProjections()
        self._ortho.setVisible(False)
        self._scene.depth_changed.connect(self._ortho.mark_depth)
        panel = self._scene.panel  # napari's layer list and controls (contrast, colormap, ...)
        panel.setVisible(False)
        self._button_layers.toggled.connect(panel.setVisible)
        for widget, stretch in ((self._scene.widget, 4), (self._ortho, 2), (panel, 1)):
            body.addWidget(widget)
            body.setStretchFactor(body.count() - 1, stretch)
        return body

    def _on_combo(self, name: str) -> None:
        if name and not self._closed and name != self._scene.focused:
            self.focus(name)

    def _on_plane(self, text: str) -> None:
        if not self._closed:
            self.set_plane(text.lower())

    def _on_reset(self) -> None:
        if not self._closed:
            if self.backend == "napari":
                self._scene.reset_view()
            elif self._scene.focused:
                self._scene.focus(self._scene.focused)

    def _update_ortho(self) -> None:
        if self.backend == "napari" and not self._ortho.isHidden():
            self._ortho.set_data(self._scene.shown(self._scene.focused))

    def _sync_controls(self, plane: str | None = None) -> None:
        """Reflect the scene in the toolbar without feeding signals back."""
        names, focused = self._scene.names(), self._scene.focused
        with _blocked(self._combo, self._button_3d, self._button_mip, self._button_ortho, self._plane):
            if [self._combo.itemText(i) for i in range(self._combo.count())] != names:
                self._combo.clear()
                self._combo.addItems(names)
            self._combo.setCurrentText(focused or "")
            self._button_3d.setChecked(self.is_3d())
            self._button_mip.setChecked(self.is_mip())
            if self.backend == "napari":
                self._button_ortho.setChecked(not self._ortho.isHidden())
            if plane is not None:
                self._plane.setCurrentText(plane.upper())
        self._update_ortho()
        shown = self._scene.shown(self._scene.focused)
        self._info.setText(describe(shown, stretched=self.backend == "napari") if shown is not None else "")
        self._update_stale()


def _toggle(text: str, tip: str) -> QPushButton:
    button = QPushButton(text)
    button.setCheckable(True)
    button.setToolTip(tip)
    return button


@contextmanager
def _blocked(*widgets: QWidget) -> Iterator[None]:
    previous = [w.blockSignals(True) for w in widgets]
    try:
        yield
    finally:
        for widget, was in zip(widgets, previous, strict=True):
            widget.blockSignals(was)
