"""The MLA editor's sensor view: where each lenslet's sub-image lands, and where they overlap.

The sensor rectangle (centred on the optical axis), a disc of the sub-image radius
per lenslet in its focal-length colour, overlap regions filled red, and red
outlines on sub-images that overlap or leave the sensor.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import pyqtgraph as pg
from qtpy.QtCore import QPointF, QRectF
from qtpy.QtGui import QColor, QPainterPath, QPolygonF
from qtpy.QtWidgets import QGraphicsEllipseItem, QGraphicsPathItem, QGraphicsRectItem

from lfm_studio.engine.design.errors import fmt
from lfm_studio.widgets.mla_editor import style as style
from lfm_studio.widgets.mla_editor.checks import SensorLayout

MAX_OVERLAPS_DRAWN = (
    300  # more overlap regions than this: the first ones are drawn, the title gives the count
)


ARC_POINTS = 16  # outline points per arc of an overlap region


def _disc(x: float, y: float, r: float) -> QRectF:
    return QRectF(x - r, y - r, 2.0 * r, 2.0 * r)


def lens_path(a: tuple[float, float], b: tuple[float, float], r: float) -> QPainterPath:
    """Where two discs of radius ``r`` centred at ``a`` and ``b`` (closer than ``2 r``) overlap.

    The region is bounded by the arc of each circle that lies inside the other: centred
    on the direction to the other centre, half-angle ``acos(d / 2r)``. Computed directly
    (a polygon of two arcs) because ``QPainterPath.intersected`` took about 0.5 ms a pair.
    """
    (ax, ay), (bx, by) = a, b
    toward = math.atan2(by - ay, bx - ax)
    half = math.acos(min(1.0, math.dist(a, b) / (2.0 * r)))
    points = []
    for (cx, cy), mid in (((ax, ay), toward), ((bx, by), toward + math.pi)):
        for k in range(ARC_POINTS + 1):
            t = mid - half + 2.0 * half * k / ARC_POINTS
            points.append(QPointF(cx + r * math.cos(t), cy + r * math.sin(t)))
    path = QPainterPath()
    path.addPolygon(QPolygonF(points))
    path.closeSubpath()
    return path


class SensorView(pg.PlotWidget):
    """A small plot of the sensor plane (micrometres) with the sub-image discs."""

    def __init__(self, parent=None) -> None:
        super().__init__(parent=parent)
        style.style_plot(self, x_label="x (µm) on the sensor", y_label="y (µm)")
        self.getViewBox().setMenuEnabled(False)
        self._sensor = QGraphicsRectItem()
        self._sensor.setPen(style.pen(style.SENSOR, 1.5))
        self._sensor.setBrush(style.brush(QColor(0, 0, 0, 90)))
        self._sensor.setZValue(-10)
        self._sensor.setVisible(False)
        self.getViewBox().addItem(self._sensor)
        self._centers = pg.ScatterPlotItem(size=5, pen=None)
        self.getViewBox().addItem(self._centers)
        self._layer: pg.ItemGroup | None = None
        self.patch_note: str | None = None  # replaces the overlap status: a patch of a larger array is drawn
        self._keys: list[object] = []
        self._overlap_items: dict[tuple, QGraphicsPathItem] = {}  # (centre a, centre b, radius) -> region
        self._discs: list[QGraphicsEllipseItem] = []
        self._overlaps: list[QGraphicsPathItem] = []
        self._layout: SensorLayout | None = None
        self._sensor_size: tuple[float, float] | None = None

    def overlap_items(self) -> list[QGraphicsPathItem]:
        """The red regions where two sub-images overlap (for tests)."""
        return list(self._overlaps)

    def disc_items(self) -> list[QGraphicsEllipseItem]:
        """One disc per lenslet (empty while the sub-image radius is unknown)."""
        return list(self._discs)

    def show_layout(
        self,
        layout: SensorLayout | None,
        sensor_size_um: tuple[float, float] | None,
        colors: Sequence[QColor],
        centers_um: Sequence[tuple[float, float]],
        selected: Sequence[int] = (),
    ) -> None:
        """Draw the sensor and the sub-images of ``layout`` (None: only the centres ``centers_um``)."""
        first = self._layout is None and self._sensor_size is None
        self._layout, self._sensor_size = layout, sensor_size_um
        if sensor_size_um is not None:
            w, h = sensor_size_um
            self._sensor.setRect(QRectF(-w / 2.0, -h / 2.0, w, h))
        self._sensor.setVisible(sensor_size_um is not None)
        n = len(layout.centers_um) if layout is not None and layout.radius_um > 0 else 0
        if n != len(self._discs):
            self._new_layer(n)
        chosen = set(selected)
        for i, disc in enumerate(self._discs):
            (x, y), color = layout.centers_um[i], colors[i]  # type: ignore[union-attr]
            issues = tuple(layout.issues.get(i, ()))  # type: ignore[union-attr]
            key = (x, y, layout.radius_um, color.rgba(), i in chosen, issues)  # type: ignore[union-attr]
            if key == self._keys[i]:
                continue
            self._keys[i] = key
            disc.setRect(_disc(x, y, layout.radius_um))  # type: ignore[union-attr]
            disc.setBrush(style.brush(style.with_alpha(color, 150 if i in chosen else 80)))
            if issues:
                disc.setPen(style.pen(style.ISSUE, 2.0))
            elif i in chosen:
                disc.setPen(style.pen(style.SELECTION, 2.0))
            else:
                disc.setPen(style.pen(color.lighter(130), 1.0))
            disc.setToolTip("\n".join([f"sub-image of lenslet {i}", *(f"• {t}" for t in issues)]))
        self._draw_overlaps(layout)
        self._centers.setData(
            pos=list(centers_um) if n == 0 else [],
            brush=[style.brush(c) for c in colors] if n == 0 else [],
        )
        self._set_title(layout, sensor_size_um)
        if first:
            self.fit()

    def _new_layer(self, n: int) -> None:
        vb = self.getViewBox()
        if self._layer is not None:
            vb.removeItem(self._layer)
        self._layer = pg.ItemGroup()
        vb.addItem(self._layer, ignoreBounds=True)
        self._discs = [QGraphicsEllipseItem(self._layer) for _ in range(n)]
        self._keys = [None] * n

    def _draw_overlaps(self, layout: SensorLayout | None) -> None:
        """Red overlap regions; a region whose two discs did not move is kept (edits of big arrays)."""
        pairs = () if layout is None else layout.overlaps[:MAX_OVERLAPS_DRAWN]
        wanted = {}
        for i, j, _ in pairs:
            a, b = layout.centers_um[i], layout.centers_um[j]  # type: ignore[union-attr]
            wanted[(a, b, layout.radius_um)] = (i, j)  # type: ignore[union-attr]
        vb = self.getViewBox()
        for key in [k for k in self._overlap_items if k not in wanted]:
            vb.removeItem(self._overlap_items.pop(key))
        self._overlaps = []
        for key, (i, j) in wanted.items():
            item = self._overlap_items.get(key)
            if item is None:
                item = self._overlap_items[key] = QGraphicsPathItem(lens_path(*key))
                item.setBrush(style.brush(style.with_alpha(style.ISSUE, 170)))
                item.setPen(style.pen(style.ISSUE, 1.0))
                item.setZValue(5)
                vb.addItem(item, ignoreBounds=True)
            item.setToolTip(f"sub-images of lenslets {i} and {j} overlap")
            self._overlaps.append(item)

    def _set_title(self, layout: SensorLayout | None, sensor_size_um: tuple[float, float] | None) -> None:
        parts = []
        if sensor_size_um is not None:
            parts.append(f"sensor {fmt(sensor_size_um[0] / 1000)} x {fmt(sensor_size_um[1] / 1000)} mm")
        if layout is not None and layout.radius_um > 0:
            parts.append(f"sub-images {fmt(2 * layout.radius_um)} µm across")
        if self.patch_note is not None:  # its overlaps say nothing about the array's
            status = self.patch_note
        elif layout is not None and layout.radius_um > 0:
            bad = len(layout.overlaps)
            drawn = f" ({MAX_OVERLAPS_DRAWN} drawn)" if bad > MAX_OVERLAPS_DRAWN else ""
            status = f"<span style='color:#ff6b6b'>{bad} overlap(s){drawn}</span>" if bad else "no overlap"
        else:
            status = "sub-image size unknown"
        # the status on a line of its own: the view is narrow, and a cut title lost it first
        self.setTitle(" · ".join(parts) + "<br>" + status, color=style.FOREGROUND, size="9pt")

    def fit(self) -> None:
        """Show the whole sensor and every sub-image."""
        extent = 0.0
        if self._sensor_size is not None:
            extent = max(self._sensor_size) / 2.0
        if self._layout is not None and self._layout.centers_um:
            r = max(self._layout.radius_um, 0.0)
            extent = max(extent, *(max(abs(x), abs(y)) + r for x, y in self._layout.centers_um))
        extent = 1.05 * (extent or 1000.0)
        self.getViewBox().setRange(xRange=(-extent, extent), yRange=(-extent, extent), padding=0.0)
