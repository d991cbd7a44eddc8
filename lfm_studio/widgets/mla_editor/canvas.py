"""The MLA editor's canvas: the MLA plane (micrometres) over the pupil footprint, in pyqtgraph.

It draws and hit-tests; it does not edit. Mouse gestures become signals in MLA
coordinates: left click (select; Shift/Ctrl adds), double click on empty space
(add), left drag from a lenslet (move the selection) or from the rim of a selected
lenslet (resize), left drag from empty space (rubber-band selection). Middle drag
pans, right drag and the wheel zoom (pyqtgraph's defaults).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pyqtgraph as pg
from qtpy.QtCore import QObject, QRectF, Qt, Signal
from qtpy.QtGui import QColor
from qtpy.QtWidgets import QGraphicsEllipseItem, QGraphicsRectItem

from lfm_studio.engine.design import LensletSpec
from lfm_studio.engine.design.errors import fmt
from lfm_studio.widgets.mla_editor import style as style

RIM_TOLERANCE_PX = 5.0
MAX_LABELS = 150  # more lenslets than this: no index labels (clutter)
MAX_GRID_LINES = 400
MAX_LEGEND = 6


class _EditViewBox(pg.ViewBox):
    """A view box that hands left-button clicks and drags to its canvas (other buttons as usual)."""

    def __init__(self, events: _Events) -> None:
        super().__init__(lockAspect=True, enableMenu=False)
        self._events = events

    def mouseClickEvent(self, ev):
        if ev.button() == Qt.MouseButton.LeftButton:
            ev.accept()
            self._events.click.emit(ev)
        else:
            super().mouseClickEvent(ev)

    def mouseDragEvent(self, ev, axis=None):
        if ev.button() == Qt.MouseButton.LeftButton and axis is None:
            ev.accept()
            self._events.drag.emit(ev)
        else:
            super().mouseDragEvent(ev, axis)


class _Events(QObject):
    click = Signal(object)
    drag = Signal(object)


def _shape_item(lens: LensletSpec) -> QGraphicsEllipseItem | QGraphicsRectItem:
    return QGraphicsRectItem() if lens.shape == "square" else QGraphicsEllipseItem()


def _rect(lens: LensletSpec, grow: float = 0.0) -> QRectF:
    (x, y), h = lens.center_um, lens.aperture_diameter_um / 2.0 + grow
    return QRectF(x - h, y - h, 2.0 * h, 2.0 * h)


def contains(lens: LensletSpec, x: float, y: float, margin: float = 0.0) -> bool:
    """True if ``(x, y)`` um lies inside the aperture of ``lens`` grown by ``margin`` um."""
    (cx, cy), h = lens.center_um, lens.aperture_diameter_um / 2.0 + margin
    if lens.shape == "square":
        return abs(x - cx) <= h and abs(y - cy) <= h
    return (x - cx) ** 2 + (y - cy) ** 2 <= h * h


class MLACanvas(pg.PlotWidget):
    """Lenslets to scale, coloured by focal length, over the pupil; selection halos and red issue outlines.

    Signals carry MLA coordinates in micrometres: ``clicked(index, additive)`` (index
    -1 on empty space), ``doubleClicked(x, y)`` on empty space, ``dragStarted(index,
    mode, x, y)`` with mode "move" or "resize", ``dragMoved(x, y)``,
    ``dragFinished(x, y)``, ``bandSelected(indices, additive)``.
    """

    clicked = Signal(int, bool)
    doubleClicked = Signal(float, float)  # noqa: N815 - Qt signal names are camelCase
    dragStarted = Signal(int, str, float, float)  # noqa: N815 - Qt signal names are camelCase
    dragMoved = Signal(float, float)  # noqa: N815 - Qt signal names are camelCase
    dragFinished = Signal(float, float)  # noqa: N815 - Qt signal names are camelCase
    bandSelected = Signal(object, bool)  # noqa: N815 - Qt signal names are camelCase

    def __init__(self, parent=None) -> None:
        self._events = _Events()
        super().__init__(parent=parent, viewBox=_EditViewBox(self._events))
        style.style_plot(self, x_label="x (µm) at the MLA", y_label="y (µm)")
        self.setFocusPolicy(Qt.FocusPolicy.StrongFocus)
        self._events.click.connect(self._on_click)
        self._events.drag.connect(self._on_drag)
        vb = self.getViewBox()
        vb.disableAutoRange()
        self._pupil = QGraphicsEllipseItem()
        self._pupil.setPen(style.pen(style.PUPIL, 1.5, Qt.PenStyle.DashLine))
        self._pupil.setBrush(style.with_alpha(style.PUPIL, 18))
        self._pupil.setZValue(-10)
        self._pupil.setVisible(False)
        vb.addItem(self._pupil, ignoreBounds=True)
        self._grid = pg.PlotCurveItem(connect="pairs", pen=style.pen(style.GRID))
        self._grid.setZValue(-5)
        vb.addItem(self._grid, ignoreBounds=True)
        self._band = QGraphicsRectItem()
        self._band.setPen(style.pen(style.SELECTION, 1.0, Qt.PenStyle.DashLine))
        self._band.setBrush(style.with_alpha(style.SELECTION, 30))
        self._band.setZValue(20)
        self._band.setVisible(False)
        vb.addItem(self._band, ignoreBounds=True)
        self._legend = pg.LegendItem(
            offset=(-8, 8), labelTextColor=style.FOREGROUND, brush=pg.mkBrush(20, 22, 26, 200)
        )
        self._legend.setParentItem(vb)
        self._legend_focals: list[float] = []
        self._lenslets: tuple[LensletSpec, ...] = ()
        self._colors: dict[float, QColor] = {}
        self._layer: pg.ItemGroup | None = None
        self._keys: list[object] = []
        self._bodies: list[QGraphicsEllipseItem | QGraphicsRectItem] = []
        self._halos: list[QGraphicsEllipseItem | QGraphicsRectItem] = []
        self._labels: list[pg.TextItem] = []
        self._selected: set[int] = set()
        self._partners: set[int] = set()
        self._issues: dict[int, list[str]] = {}
        self._pupil_radius: float | None = None
        self._snap_pitch: float | None = None
        self._mode: str | None = None
        self._start = (0.0, 0.0)
        self._additive = False

    # ----- what is shown -----

    def show_lenslets(self, lenslets: Sequence[LensletSpec], colors: dict[float, QColor]) -> None:
        """Draw ``lenslets`` with a fill colour per focal length (``colors``); only changed ones are redrawn."""
        lenslets = tuple(lenslets)
        old = self._lenslets
        self._lenslets, self._colors = lenslets, colors
        if len(lenslets) != len(old) or any(a.shape != b.shape for a, b in zip(lenslets, old, strict=True)):
            self._rebuild()
        else:
            for i, lens in enumerate(lenslets):
                if lens is not old[i] and lens != old[i]:
                    self._place(i, lens)
        self._restyle()
        self._draw_grid()
        self.show_legend(colors)

    def show_selection(self, selected: Sequence[int], partners: Sequence[int] = ()) -> None:
        """Halo the ``selected`` lenslets (and, fainter, their symmetric ``partners``)."""
        self._selected, self._partners = set(selected), set(partners) - set(selected)
        self._restyle()

    def show_issues(self, issues: dict[int, list[str]]) -> None:
        """Outline in red the lenslets with a reason in ``issues`` (also their tooltips)."""
        self._issues = issues
        self._restyle()

    def show_legend(self, colors: dict[float, QColor]) -> None:
        """List the focal lengths with their colours (shortest, longest and a few between if many)."""
        focals = sorted(colors)
        if focals == self._legend_focals:
            return
        self._legend_focals = focals
        self._legend.clear()
        shown = (
            focals
            if len(focals) <= MAX_LEGEND
            else [focals[round(k * (len(focals) - 1) / (MAX_LEGEND - 1))] for k in range(MAX_LEGEND)]
        )
        for f in shown:
            sample = pg.ScatterPlotItem(
                symbol="o", size=12, brush=pg.mkBrush(colors[f]), pen=style.pen(colors[f].lighter(140))
            )
            self._legend.addItem(sample, f"f = {fmt(f)} mm")
        self._legend.setVisible(bool(focals))

    def set_pupil_radius(self, radius_um: float | None) -> None:
        """Draw the pupil footprint, a dashed circle of ``radius_um`` (None: hide it)."""
        self._pupil_radius = radius_um
        if radius_um is not None:
            r = float(radius_um)
            self._pupil.setRect(QRectF(-r, -r, 2 * r, 2 * r))
        self._pupil.setVisible(radius_um is not None)
        title = (
            "MLA plane"
            if radius_um is None
            else f"MLA plane · pupil footprint Ø {fmt(2 * radius_um / 1000)} mm (dashed)"
        )
        self.setTitle(title, color=style.FOREGROUND, size="9pt")
        self._draw_grid()

    def set_snap_grid(self, pitch_um: float | None) -> None:
        """Draw the snapping grid of ``pitch_um`` (None: hide it)."""
        self._snap_pitch = pitch_um
        self._draw_grid()

    def fit(self) -> None:
        """Show the pupil and every lenslet."""
        reach = max([lens.reach_um for lens in self._lenslets] + [self._pupil_radius or 0.0])
        reach = 1.05 * (reach or 1000.0)
        self.getViewBox().setRange(xRange=(-reach, reach), yRange=(-reach, reach), padding=0.0)

    def body_item(self, index: int) -> QGraphicsEllipseItem | QGraphicsRectItem:
        """The graphics item drawing lenslet ``index`` (for tests and tooltips)."""
        return self._bodies[index]

    def view_to_scene(self, x: float, y: float):
        """Scene position of MLA point ``(x, y)`` um."""
        return self.getViewBox().mapViewToScene(pg.Point(x, y))

    # ----- hit tests -----

    def _pixel_um(self) -> float:
        px = self.getViewBox().viewPixelSize()
        return float(max(abs(px[0]), abs(px[1])))

    def index_at(self, x: float, y: float) -> int:
        """Topmost lenslet whose aperture contains ``(x, y)`` um, or -1."""
        for i in range(len(self._lenslets) - 1, -1, -1):
            if contains(self._lenslets[i], x, y):
                return i
        return -1

    def rim_index_at(self, x: float, y: float) -> int:
        """A selected lenslet whose rim passes within a few pixels of ``(x, y)`` um, or -1."""
        tol = RIM_TOLERANCE_PX * self._pixel_um()
        for i in sorted(self._selected, reverse=True):
            lens = self._lenslets[i]
            if contains(lens, x, y, tol) and not contains(lens, x, y, -tol):
                return i
        return -1

    # ----- mouse gestures -----

    def _view_pos(self, scene_pos) -> tuple[float, float]:
        p = self.getViewBox().mapSceneToView(scene_pos)
        return (float(p.x()), float(p.y()))

    @staticmethod
    def _is_additive(ev) -> bool:
        mods = ev.modifiers()
        return bool(mods & Qt.KeyboardModifier.ShiftModifier or mods & Qt.KeyboardModifier.ControlModifier)

    def _on_click(self, ev) -> None:
        x, y = self._view_pos(ev.scenePos())
        index = self.index_at(x, y)
        if ev.double():
            if index < 0:
                self.doubleClicked.emit(x, y)
            return
        self.clicked.emit(index, self._is_additive(ev))

    def _on_drag(self, ev) -> None:
        x, y = self._view_pos(ev.scenePos())
        if ev.isStart():
            self._start = self._view_pos(ev.buttonDownScenePos())
            self._additive = self._is_additive(ev)
            rim = self.rim_index_at(*self._start)
            index = rim if rim >= 0 else self.index_at(*self._start)
            self._mode = "resize" if rim >= 0 else ("move" if index >= 0 else "band")
            if self._mode != "band":
                self.dragStarted.emit(index, self._mode, *self._start)
        if self._mode is None:  # cancelled (Escape) until the button comes up
            return
        if self._mode == "band":
            self._band_to(x, y, finish=ev.isFinish())
        elif ev.isFinish():
            self._mode = None
            self.dragFinished.emit(x, y)
        else:
            self.dragMoved.emit(x, y)
        if ev.isFinish():
            self._mode = None

    def cancel_drag(self) -> None:
        """Ignore the rest of the current drag (until the button is released)."""
        self._mode = None
        self._band.setVisible(False)

    def _band_to(self, x: float, y: float, *, finish: bool) -> None:
        x0, y0 = self._start
        rect = QRectF(min(x0, x), min(y0, y), abs(x - x0), abs(y - y0))
        self._band.setRect(rect)
        self._band.setVisible(not finish)
        if finish:
            inside = [i for i, lens in enumerate(self._lenslets) if rect.contains(*lens.center_um)]
            self.bandSelected.emit(inside, self._additive)

    # ----- drawing -----

    def _rebuild(self) -> None:
        # All lenslet items hang under one layer item: adding 10^4 items one by one through
        # ViewBox.addItem costs seconds; replacing the layer drops them all at once.
        vb = self.getViewBox()
        if self._layer is not None:
            vb.removeItem(self._layer)
        self._layer = pg.ItemGroup()
        vb.addItem(self._layer, ignoreBounds=True)
        self._bodies, self._halos, self._labels, self._keys = [], [], [], []
        for i, lens in enumerate(self._lenslets):
            halo, body = _shape_item(lens), _shape_item(lens)
            halo.setZValue(0)
            body.setZValue(1)
            halo.setBrush(style.brush(None))
            halo.setParentItem(self._layer)
            body.setParentItem(self._layer)
            self._halos.append(halo)
            self._bodies.append(body)
            self._keys.append(None)
            if len(self._lenslets) <= MAX_LABELS:
                label = pg.TextItem(str(i), color=style.FOREGROUND, anchor=(0.5, 0.5))
                label.setZValue(2)
                label.setParentItem(self._layer)
                self._labels.append(label)
            self._place(i, lens)

    def _place(self, i: int, lens: LensletSpec) -> None:
        self._bodies[i].setRect(_rect(lens))
        self._halos[i].setRect(_rect(lens))
        if self._labels:
            self._labels[i].setPos(*lens.center_um)

    def _restyle(self) -> None:
        """Restyle the lenslets whose look changed (colour, selection, issues, geometry for the tooltip)."""
        grey = QColor("#888888")
        for i, lens in enumerate(self._lenslets):
            color = self._colors.get(lens.focal_length_mm, grey)
            issues = tuple(self._issues.get(i, ()))
            look = 2 if i in self._selected else (1 if i in self._partners else 0)
            key = (lens, color.rgba(), look, issues)
            if key == self._keys[i]:
                continue
            self._keys[i] = key
            body = self._bodies[i]
            body.setBrush(style.brush(style.with_alpha(color, 215 if look == 2 else 140)))
            body.setPen(style.pen(style.ISSUE, 2.5) if issues else style.pen(color.lighter(140), 1.2))
            x, y = lens.center_um
            tip = (
                f"lenslet {i}: centre ({fmt(x)}, {fmt(y)}) µm, diameter {fmt(lens.aperture_diameter_um)} µm, "
                f"f {fmt(lens.focal_length_mm)} mm"
            )
            body.setToolTip("\n".join([tip, *(f"• {t}" for t in issues)]))
            halo = self._halos[i]
            halo.setVisible(look > 0)
            if look:
                halo.setPen(style.pen(style.SELECTION, 7) if look == 2 else style.pen(style.PARTNER, 4))

    def _draw_grid(self) -> None:
        pitch = self._snap_pitch
        if pitch is None:
            self._grid.setData([], [])
            return
        extent = max([lens.reach_um for lens in self._lenslets] + [self._pupil_radius or 0.0]) * 1.1
        if extent <= 0 or 2 * extent / pitch > MAX_GRID_LINES:
            self._grid.setData([], [])
            return
        n = int(extent // pitch) + 1
        ticks = np.arange(-n, n + 1) * pitch
        lo, hi = -n * pitch, n * pitch
        xs = np.concatenate([np.repeat(ticks, 2), np.tile([lo, hi], ticks.size)])
        ys = np.concatenate([np.tile([lo, hi], ticks.size), np.repeat(ticks, 2)])
        self._grid.setData(xs, ys)
