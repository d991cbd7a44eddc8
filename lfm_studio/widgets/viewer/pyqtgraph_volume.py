"""pyqtgraph views of PSF stacks, images and volumes (no OpenGL needed).

:class:`PyqtgraphVolume` is the fallback of :class:`~lfm_studio.widgets.psf_viewer.PSFViewer`
when napari's OpenGL canvas cannot run: an ``ImageView`` of the lateral slices with a depth
slider (its timeline, in sample-side micrometres) next to :class:`OrthoProjections`, the
XZ and YZ maximum projections with the current depth marked. Axes are in micrometres.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pyqtgraph as pg
from qtpy.QtCore import QRectF
from qtpy.QtGui import QImage
from qtpy.QtWidgets import QHBoxLayout, QVBoxLayout, QWidget

from lfm_studio.widgets.viewer.display_data import depth_axis_um, nearest_depth_index

if TYPE_CHECKING:
    from lfm_studio.widgets.viewer.display_data import DisplayData

_GRAY = "CET-L1"


def colormap(name: str) -> pg.ColorMap:
    """A pyqtgraph colormap for a napari colormap name (``gray`` -> ``CET-L1``)."""
    return pg.colormap.get(_GRAY if name == "gray" else name)


def displayed_block(shown: DisplayData) -> np.ndarray:
    """The ``(Z, Y, X)`` or ``(Y, X)`` block shown: leading axes at their initial (or central) step."""
    spatial = 3 if shown.has_depth else 2
    index = tuple(shown.initial_step.get(a, n // 2) for a, n in enumerate(shown.data.shape[:-spatial]))
    return shown.data[index]


def grab_array(widget: QWidget) -> np.ndarray:
    """``widget`` rendered into a ``(H, W, 4)`` uint8 RGBA array."""
    image = widget.grab().toImage().convertToFormat(QImage.Format.Format_RGBA8888)
    array = np.frombuffer(image.constBits(), dtype=np.uint8, count=image.sizeInBytes())
    return array.reshape(image.height(), image.bytesPerLine() // 4, 4)[:, : image.width()].copy()


class OrthoProjections(QWidget):
    """XZ and YZ maximum-intensity projections of a ``(Z, Y, X)`` block, axes in micrometres.

    The depth axis is drawn at whatever aspect fills the panel (its tick labels stay in um),
    so a thin PSF stack is still readable.
    """

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self._plots, self._images, self._lines = [], [], []
        for title, across in (("XZ: max over y", "x (µm)"), ("YZ: max over x", "y (µm)")):
            plot = pg.PlotWidget(title=title)
            plot.setLabel("bottom", across)
            plot.setLabel("left", "z (µm)")
            plot.getPlotItem().invertY(True)  # depth grows downwards, like the sliders
            image = pg.ImageItem(axisOrder="row-major")
            line = pg.InfiniteLine(angle=0, movable=False, pen=pg.mkPen("c", width=1))
            line.setVisible(False)
            plot.addItem(image)
            plot.addItem(line)
            layout.addWidget(plot)
            self._plots.append(plot)
            self._images.append(image)
            self._lines.append(line)

    def set_data(self, shown: DisplayData | None) -> None:
        """Show ``shown``'s projections (``None`` or a 2-D image: empty panels)."""
        if shown is None or not shown.has_depth:
            for image in self._images:
                image.clear()
            return
        block = displayed_block(shown)
        depths = depth_axis_um(shown)
        dz = shown.scale_um[-3]
        z0, z_span = depths[0] - dz / 2, dz * block.shape[0]
        for image, plot, axis in zip(self._images, self._plots, (-1, -2), strict=True):
            projection = block.max(axis=1 if axis == -1 else 2)  # (Z, X) then (Z, Y)
            if shown.contrast_limits is None:  # per-depth contrast, like the slices
                projection = projection / np.maximum(projection.max(axis=1, keepdims=True), 1e-30)
            step, start = shown.scale_um[axis], shown.translate_um[axis]
            image.setImage(projection, autoLevels=True)
            image.setColorMap(colormap(shown.colormap))
            image.setRect(QRectF(start - step / 2, z0, step * projection.shape[1], z_span))
            plot.getPlotItem().autoRange(padding=0)

    def mark_depth(self, depth_um: float | None) -> None:
        """Draw the current slice depth (sample-side um) on both projections; ``None`` hides it."""
        for line in self._lines:
            line.setVisible(depth_um is not None)
            if depth_um is not None:
                line.setPos(depth_um)


class PyqtgraphVolume(QWidget):
    """Layers by name shown with pyqtgraph: lateral slices with a depth slider, XZ/YZ projections."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self._shown: dict[str, DisplayData] = {}
        self.focused: str | None = None
        plot = pg.PlotItem()
        plot.setLabel("bottom", "x (µm)")
        plot.setLabel("left", "y (µm)")
        self.image_view = pg.ImageView(view=plot)
        self.image_view.ui.roiBtn.hide()
        self.image_view.ui.menuBtn.hide()
        timeline = self.image_view.ui.roiPlot.getPlotItem()  # the depth slider: drag the yellow line
        timeline.setLabel("bottom", "z (µm, sample side): drag the yellow line or use the arrow keys")
        self.image_view.sigTimeChanged.connect(self._on_time)
        self.projections = OrthoProjections()
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.image_view, 3)
        layout.addWidget(self.projections, 2)

    def put(self, shown: DisplayData) -> bool:
        """Show ``shown`` under its name; True when the name is new (the view then switches to it).

        New data for the layer on screen keeps the depth shown (its nearest slice).
        """
        created = shown.name not in self._shown
        kept = None if created or shown.name != self.focused else self.current_depth()
        self._shown[shown.name] = shown
        if created or shown.name == self.focused:
            self.focus(shown.name)
        if kept is not None and shown.has_depth:
            self.image_view.setCurrentIndex(nearest_depth_index(shown, kept))
        return created

    def focus(self, name: str, *, reset: bool = True) -> None:
        shown = self._shown[name]
        self.focused = name
        block = displayed_block(shown)
        y, x = shown.scale_um[-2], shown.scale_um[-1]
        origin = (shown.translate_um[-1] - x / 2, shown.translate_um[-2] - y / 2)
        levels = shown.contrast_limits
        if shown.has_depth:
            axes, xvals = {"t": 0, "y": 1, "x": 2}, depth_axis_um(shown)
        else:
            axes, xvals = {"y": 0, "x": 1}, None
        self.image_view.setImage(
            block, axes=axes, xvals=xvals, pos=origin, scale=(x, y), levels=levels, autoLevels=levels is None
        )
        self.image_view.setColorMap(colormap(shown.colormap))
        self.image_view.view.setAspectLocked(True)
        if shown.has_depth:
            self.image_view.setCurrentIndex(block.shape[0] // 2)
            self.image_view.ui.splitter.setSizes([1000, 130])  # room for the depth timeline
        self.projections.set_data(shown)
        self._on_time()

    def names(self) -> list[str]:
        return list(self._shown)

    def layer(self, name: str) -> DisplayData | None:
        return self._shown.get(name)

    def shown(self, name: str | None) -> DisplayData | None:
        return self._shown.get(name) if name else None

    def current_depth(self) -> float | None:
        """Depth (sample-side um) of the slice shown, or ``None`` for a 2-D image."""
        shown = self._shown.get(self.focused) if self.focused else None
        if shown is None or not shown.has_depth:
            return None
        return float(depth_axis_um(shown)[self.image_view.currentIndex])

    def clear(self) -> None:
        self._shown.clear()
        self.focused = None
        self.image_view.clear()
        self.projections.set_data(None)
        self.projections.mark_depth(None)

    def screenshot(self) -> np.ndarray:
        return grab_array(self)

    def _on_time(self, *_: object) -> None:
        shown = self._shown.get(self.focused) if self.focused else None
        if shown is not None and shown.has_depth and shown.contrast_limits is None:
            frame = displayed_block(shown)[self.image_view.currentIndex]  # per-slice contrast, like napari
            low, high = float(frame.min()), float(frame.max())
            self.image_view.setLevels(low, high if high > low else low + 1.0)
        self.projections.mark_depth(self.current_depth())
