"""Plots (pyqtgraph): PSF profiles, design metrics against the zebrafish requirements, RL convergence.

Views only: each observes the state (when given one) and redraws; none computes anything
heavier than picking values out of a result (the profiles are computed with the PSF, on
the worker). The main window places them in separate docks.
"""

from __future__ import annotations

import os

os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

import pyqtgraph as pg
from qtpy.QtCore import Qt
from qtpy.QtGui import QBrush, QColor
from qtpy.QtWidgets import (
    QAbstractItemView,
    QHeaderView,
    QLabel,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.performance import DesignMetrics
from lfm_studio.engine.performance.report import UNIT_SCALE
from lfm_studio.ui.measured_note import MEASURED_LATER, MEASURED_LATER_WHY, measured_note
from lfm_studio.ui.results import PSFResult
from lfm_studio.ui.state import StudioState
from lfm_studio.ui.table_fit import fit_columns
from lfm_studio.ui.unit_text import shown_unit
from lfm_studio.widgets.stale_mark import StaleMark

PASS, FAIL, UNKNOWN = QColor("#2e7d32"), QColor("#c62828"), QColor("#757575")
_QUANTITY = {
    "field_of_view": "FoV",
    "depth_of_field": "DoF",
    "lateral_resolution": "Lateral res.",
    "axial_resolution": "Axial res.",
}
_BASIS = {"closed_form": "formula", "measured": "measured"}


def _plot(title: str, x_label: str, y_label: str) -> pg.PlotWidget:
    widget = pg.PlotWidget(background="w")
    item = widget.getPlotItem()
    item.setTitle(title, color="k", size="10pt")
    item.setLabel("bottom", x_label)
    item.setLabel("left", y_label)
    item.showGrid(x=True, y=True, alpha=0.25)
    widget.setMinimumSize(200, 100)
    return widget


STALE_OPACITY = 0.3  # opacity of a stale plot's curves


class _StateView(QWidget):
    """A plot that observes some of the state's signals (disconnect before destruction).

    :meth:`set_stale` puts a label over the view (and fades the plot items in ``_dimmed``)
    while what it shows no longer matches the design (see :mod:`lfm_studio.ui.stale_marks`).
    """

    def __init__(self, state: StudioState | None, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.state = state
        self._connections: list[tuple[object, object]] = []
        self._dimmed: list[pg.GraphicsObject] = []
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self.stale_label = QLabel(self)
        self.stale_label.setObjectName("staleLabel")
        self.stale_label.setWordWrap(True)
        self.stale_label.setVisible(False)
        layout.addWidget(self.stale_label)

    @property
    def stale_text(self) -> str | None:
        """The stale label's text, or None while the view is fresh."""
        return None if self.stale_label.isHidden() else self.stale_label.text()

    def set_stale(self, mark: StaleMark | None) -> None:
        """Mark the view stale with ``mark`` (greyed, with a label coloured by its severity), or fresh with None."""
        if mark is not None:
            background, colour = mark.colours
            self.stale_label.setStyleSheet(
                f"QLabel {{ background: {background}; color: {colour}; padding: 3px; }}"
            )
        self.stale_label.setText(mark.text if mark is not None else "")
        self.stale_label.setVisible(mark is not None)
        for item in self._dimmed:
            item.setOpacity(STALE_OPACITY if mark is not None else 1.0)

    def is_dimmed(self) -> bool:
        """Whether the view's curves are faded out as stale."""
        return any(item.opacity() < 1.0 for item in self._dimmed)

    def _observe(self, signal, slot, current) -> None:
        signal.connect(slot)
        self._connections.append((signal, slot))
        slot(current)

    def disconnect_state(self) -> None:
        for signal, slot in self._connections:
            signal.disconnect(slot)
        self._connections.clear()


FULL_NAME, PREVIEW_NAME = "full PSF", "quick preview"  # the profile plots' key
PROFILE_COLOUR = "#1565c0"
_KEY_GAP = "&nbsp;&nbsp;&nbsp;"


def keyed_title(title: str, entries: list[tuple[str, str]]) -> str:
    """``title`` with a key line below it: ``(sample, name)`` pairs, the sample an HTML snippet.

    The key sits in the plot's title, above the data, never over a curve (a legend box inside the
    axes hid part of the lateral profile, walk 4).
    """
    if not entries:
        return title
    key = _KEY_GAP.join(f"{sample} {name}" for sample, name in entries)
    return f'{title}<br><span style="font-size:8pt;">{key}</span>'


def show_title(item: pg.PlotItem, html: str, *, size: str) -> None:
    """``item.setTitle(html)`` in black, the title row as tall as its lines: pyqtgraph fixes it at
    30 px, which cut the first of three lines (a note and a key under the title)."""
    item.setTitle(html, color="k", size=size)
    height = item.titleLabel.item.boundingRect().height()
    item.titleLabel.setMaximumHeight(height)
    item.layout.setRowFixedHeight(0, height)


def _sample(text: str) -> str:
    return f'<span style="color:{PROFILE_COLOUR};">{text}</span>'


class ProfilePlots(_StateView):
    """Lateral and axial PSF profiles of the current full stack (dashed: the quick preview).

    The key (which curve is which; the dashed one is not obvious) is in each plot's title and
    names the curves shown.
    """

    LATERAL_TITLE, AXIAL_TITLE = "Lateral PSF profile (sharpest depth)", "Peak intensity per depth"

    def __init__(self, state: StudioState | None = None, parent: QWidget | None = None) -> None:
        super().__init__(state, parent)
        self.lateral_plot = _plot(self.LATERAL_TITLE, "x (µm, sample)", "intensity")
        self.axial_plot = _plot(self.AXIAL_TITLE, "depth (µm)", "peak")
        self.layout().addWidget(self.lateral_plot)
        self.layout().addWidget(self.axial_plot)
        solid, dashed = (
            pg.mkPen(PROFILE_COLOUR, width=2),
            pg.mkPen(PROFILE_COLOUR, width=1.5, style=Qt.PenStyle.DashLine),
        )
        self.lateral_curve = self.lateral_plot.plot(pen=solid, name=FULL_NAME)
        self.axial_curve = self.axial_plot.plot(
            pen=solid, symbol="o", symbolSize=4, symbolBrush=PROFILE_COLOUR, name=FULL_NAME
        )
        self.lateral_preview = self.lateral_plot.plot(pen=dashed, name=PREVIEW_NAME)
        self.axial_preview = self.axial_plot.plot(pen=dashed, symbol="t", symbolSize=5, name=PREVIEW_NAME)
        self._dimmed = [self.lateral_curve, self.axial_curve, self.lateral_preview, self.axial_preview]
        if state is not None:
            self._observe(state.psf_changed, self.show_result, state.psf)
            self._observe(state.preview_changed, self.show_preview, state.preview)

    def show_preview(self, result: PSFResult | None) -> None:
        self.show_result(result, preview=True)

    def show_result(self, result: PSFResult | None, *, preview: bool = False) -> None:
        lateral, axial = (
            (self.lateral_preview, self.axial_preview) if preview else (self.lateral_curve, self.axial_curve)
        )
        if result is None or result.profiles is None:
            lateral.setData([], [])
            axial.setData([], [])
        else:
            p = result.profiles
            lateral.setData((p.lateral_x * 1e6).numpy(), p.lateral.numpy())
            axial.setData((p.axial_z * 1e6).numpy(), p.axial.numpy())
        self._show_keys()

    def _show_keys(self) -> None:
        """Title each plot with the key of the curves it shows."""
        for plot, title, curves, markers in (
            (self.lateral_plot, self.LATERAL_TITLE, (self.lateral_curve, self.lateral_preview), ("", "")),
            (self.axial_plot, self.AXIAL_TITLE, (self.axial_curve, self.axial_preview), ("●", "▲")),
        ):
            show_title(plot.getPlotItem(), keyed_title(title, _key_entries(curves, markers)), size="10pt")


def _key_entries(
    curves: tuple[pg.PlotDataItem, pg.PlotDataItem], markers: tuple[str, str]
) -> list[tuple[str, str]]:
    """Key entries of the (full, preview) curves that hold data: a solid or dashed line with its marker."""
    lines = ("━", "╌")
    return [
        (_sample(f"{line}{marker}{line}"), name)
        for curve, line, marker, name in zip(curves, lines, markers, (FULL_NAME, PREVIEW_NAME), strict=True)
        if _has_data(curve)
    ]


def _has_data(curve: pg.PlotDataItem) -> bool:
    x, _ = curve.getData()
    return x is not None and len(x) > 0


_SHORT = {
    "field_of_view": "FoV",
    "depth_of_field": "DoF",
    "lateral_resolution": "lateral",
    "axial_resolution": "axial",
}


class RequirementsView(_StateView):
    """Design metrics against the requirements: a pass/fail summary, a bar per check, a table."""

    def __init__(self, state: StudioState | None = None, parent: QWidget | None = None) -> None:
        super().__init__(state, parent)
        layout = self.layout()
        self.summary = QLabel(self)
        self.summary.setWordWrap(True)
        layout.addWidget(self.summary)
        self.note = QLabel(MEASURED_LATER, self)  # per design kind: measured later, or why never
        self.note.setToolTip(MEASURED_LATER_WHY)
        self.note.setWordWrap(True)
        self.note.setStyleSheet("color: gray;")
        layout.addWidget(self.note)
        self.chart = _plot("value / requirement (≥ 1 passes)", "", "score")
        self.chart.getPlotItem().addLine(y=1.0, pen=pg.mkPen("k", style=Qt.PenStyle.DashLine))
        self.chart.setMouseEnabled(x=False, y=False)
        self.chart.setMinimumHeight(90)
        layout.addWidget(self.chart, 1)
        self.table = QTableWidget(0, 4, self)
        self.table.setHorizontalHeaderLabels(["Requirement", "Basis", "Value", "Result"])
        self.table.verticalHeader().setVisible(False)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        fit_columns(self.table)  # a stretched last column kept 100 px and pushed the others out of view
        self.table.verticalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        layout.addWidget(self.table, 1)
        self._bars: list[pg.GraphicsObject] = []
        if state is not None:
            self._observe(state.metrics_changed, self.show_metrics, state.metrics)

    def rows(self) -> list[tuple[str, str, str, str]]:
        """The table as text (for tests and screen readers)."""
        return [
            tuple(self.table.item(r, c).text() for c in range(self.table.columnCount()))
            for r in range(self.table.rowCount())
        ]

    def show_metrics(self, metrics: DesignMetrics | None) -> None:
        plot = self.chart.getPlotItem()
        for bar in self._bars:
            plot.removeItem(bar)
        self._bars = []
        checks = () if metrics is None else metrics.requirements
        self.table.setRowCount(len(checks))
        if metrics is None:
            self.summary.setText("")
            return
        text, tip = measured_note(metrics)
        self.note.setText(text)
        self.note.setToolTip(tip)
        met = metrics.requirements_met
        verdict = {True: "meets", False: "does not meet", None: "may meet"}[met]
        failed = sum(c.passed is False for c in checks)
        colour = {True: PASS, False: FAIL, None: UNKNOWN}[met].name()
        self.summary.setText(
            f"<b style='color:{colour}'>{verdict.capitalize()} the {metrics.requirement_set} "
            f"requirements</b> ({failed} of {len(checks)} checks fail)"
        )
        ticks, scores, brushes = [], [], []
        for row, check in enumerate(checks):
            scale, unit = UNIT_SCALE[check.unit], f" {shown_unit(check.unit)}" if check.unit else ""
            symbol = {">=": "≥", "<=": "≤"}.get(check.comparison, check.comparison)
            quantity = _QUANTITY.get(check.quantity, check.quantity)
            name = f"{quantity} {symbol} {check.limit / scale:.4g}{unit}"
            if check.criterion:  # on a line of its own: one long line pushed Value out of the narrow dock
                name = f"{name}\n{check.criterion}"
            value = "n/a" if check.value is None else f"{check.value / scale:.4g}{unit}"
            result = {True: "PASS", False: "FAIL", None: "?"}[check.passed]
            colour = {True: PASS, False: FAIL, None: UNKNOWN}[check.passed]
            basis = _BASIS.get(check.basis, check.basis)
            for column, text in enumerate((name, basis, value, result)):
                item = QTableWidgetItem(text)
                item.setToolTip(
                    f"{name}: {value} ({'closed-form estimate' if basis == 'formula' else 'measured on the PSF'})"
                )
                if column == 3:
                    item.setForeground(QBrush(QColor("white")))
                    item.setBackground(QBrush(colour))
                    item.setTextAlignment(Qt.AlignmentFlag.AlignCenter)
                self.table.setItem(row, column, item)
            score = 0.0
            if check.value:
                score = check.value / check.limit if check.comparison == ">=" else check.limit / check.value
            short = _SHORT.get(check.quantity, check.quantity)
            ticks.append((row, f"{short}*" if check.basis == "measured" else short))
            scores.append(score)
            brushes.append(pg.mkBrush(colour))
        if checks:
            bars = pg.BarGraphItem(x=list(range(len(checks))), height=scores, width=0.6, brushes=brushes)
            plot.addItem(bars)
            self._bars.append(bars)
            plot.getAxis("bottom").setTicks([ticks])
            plot.setYRange(0, max(1.5, max(scores) * 1.1))


class ConvergencePlot(_StateView):
    """Richardson-Lucy convergence: NCC with the ground truth after each iteration (live).

    NCC (Pearson correlation) is read against 0, the score of the all-zero, a constant or a
    shuffled volume (the dashed line); PSNR on a sparse phantom starts near its ceiling.
    """

    def __init__(self, state: StudioState | None = None, parent: QWidget | None = None) -> None:
        super().__init__(state, parent)
        self.plot = _plot("Richardson-Lucy convergence", "iteration", "NCC with the ground truth")
        self.layout().addWidget(self.plot)
        pen = pg.mkPen("#6a1b9a", width=2)
        self.curve = self.plot.plot(pen=pen, symbol="o", symbolSize=4, symbolBrush="#6a1b9a")
        self._dimmed = [self.curve]
        self.floor = pg.InfiniteLine(
            pos=0.0, angle=0, pen=pg.mkPen("#757575", width=1, style=Qt.PenStyle.DashLine),
            label="all-zero floor", labelOpts={"position": 0.85, "color": "#757575"},
        )  # fmt: skip
        self.plot.addItem(self.floor)
        self.plot.setYRange(0.0, 1.0)
        if state is not None:
            self._observe(state.convergence_changed, self.show_curves, state.convergence)

    def show_curves(self, curves: tuple[tuple[float, ...], tuple[float, ...]]) -> None:
        """Plot the first curve of ``(NCC per iteration, relative change per iteration)``."""
        ncc = list(curves[0])
        self.curve.setData(list(range(1, len(ncc) + 1)), ncc)
        self.plot.setYRange(min(0.0, *ncc) if ncc else 0.0, 1.0)
