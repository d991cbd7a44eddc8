"""Colours and pens shared by the MLA editor's canvas and sensor view (dark, napari-like theme)."""

from __future__ import annotations

from collections.abc import Iterable
from functools import lru_cache

import pyqtgraph as pg
from qtpy.QtCore import Qt
from qtpy.QtGui import QBrush, QColor, QPen

BACKGROUND = "#262930"  # napari's dark canvas
FOREGROUND = "#d6d7db"
ISSUE = QColor("#ff3b3b")
SELECTION = QColor(255, 213, 79, 200)
PARTNER = QColor(255, 213, 79, 110)
PUPIL = QColor("#9aa0aa")
SENSOR = QColor("#e8e8e8")
GRID = QColor(255, 255, 255, 28)
_COLORMAP = pg.colormap.get("viridis")


def focal_colors(focal_lengths_mm: Iterable[float]) -> dict[float, QColor]:
    """A colour per distinct focal length: viridis from short (blue) to long (yellow-green)."""
    values = sorted(set(focal_lengths_mm))
    if not values:
        return {}
    lo, hi = values[0], values[-1]
    out = {}
    for f in values:
        t = 0.6 if hi == lo else 0.25 + 0.65 * (f - lo) / (hi - lo)  # dark purple is lost on the dark canvas
        out[f] = QColor(_COLORMAP.map(t, mode=pg.ColorMap.QCOLOR))
    return out


def with_alpha(color: QColor, alpha: int) -> QColor:
    """A copy of ``color`` with ``alpha`` (0-255)."""
    c = QColor(color)
    c.setAlpha(alpha)
    return c


@lru_cache(maxsize=512)
def _pen(rgba: int, width: float, style: Qt.PenStyle) -> QPen:
    p = pg.mkPen(QColor.fromRgba(rgba), width=width)
    p.setStyle(style)
    p.setCosmetic(True)
    return p


def pen(color: QColor | str, width: float = 1.0, style: Qt.PenStyle = Qt.PenStyle.SolidLine) -> QPen:
    """A cosmetic pen (its width in screen pixels, whatever the zoom); cached, do not modify it."""
    return _pen(QColor(color).rgba(), float(width), style)


@lru_cache(maxsize=512)
def _brush(rgba: int | None) -> QBrush:
    return pg.mkBrush(None) if rgba is None else pg.mkBrush(QColor.fromRgba(rgba))


def brush(color: QColor | str | None) -> QBrush:
    """A solid brush (None: no fill); cached, do not modify it."""
    return _brush(None if color is None else QColor(color).rgba())


def style_plot(plot: pg.PlotWidget, *, x_label: str, y_label: str) -> None:
    """Dark background, labelled axes in micrometres, square pixels, faint grid."""
    plot.setBackground(BACKGROUND)
    item = plot.getPlotItem()
    for name, label in (("bottom", x_label), ("left", y_label)):
        axis = item.getAxis(name)
        axis.setLabel(label)
        axis.setPen(pen(FOREGROUND))
        axis.setTextPen(pen(FOREGROUND))
    item.showGrid(x=True, y=True, alpha=0.15)
    item.setAspectLocked(True)
    item.hideButtons()
