"""The Pareto plot (PNG): time against PSF error, log-log, one panel per case.

Each setting is a labelled grey point, the Pareto front a red line through its
points, the presets large blue points. Drawn with pyqtgraph's ImageExporter on Qt's
offscreen platform (imported lazily: the engine never imports Qt); without pyqtgraph
a small hand-made raster (points and front, no text) is written instead.
Errors below ``ERROR_FLOOR`` (e.g. exactly 0) are drawn at the floor.
"""

from __future__ import annotations

import itertools
import math
import os
import struct
import zlib
from pathlib import Path

from lfm_studio.bench.sweep import CaseResult
from lfm_studio.engine.atomic_write import atomic_write

ERROR_FLOOR = 1e-9
PANEL_SIZE = (720, 520)  # pixels per case panel


def _points(result: CaseResult) -> list[tuple[float, float, str, bool, bool]]:
    return [
        (r.seconds, max(r.psf_error, ERROR_FLOOR), r.label, r.front, r.knob == "preset")
        for r in result.rows
        if r.seconds > 0 and not math.isnan(r.psf_error)
    ]


def write_pareto_png(
    results: list[CaseResult], path: str | os.PathLike[str], *, overwrite: bool = False
) -> Path:
    """Write the plot of ``results`` to ``path`` (PNG); refuses to replace a file unless ``overwrite``."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists. Fix: choose another --out folder or pass --overwrite.")
    try:
        data = _render_pyqtgraph(results)
    except ImportError:
        data = _render_raster(results)
    return atomic_write(path, lambda fh: fh.write(data), overwrite=overwrite)


def _render_pyqtgraph(results: list[CaseResult]) -> bytes:
    os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")
    import pyqtgraph as pg
    import pyqtgraph.exporters as exporters
    from pyqtgraph.Qt import QtCore, QtGui, QtWidgets

    app = QtWidgets.QApplication.instance()
    if app is None:  # headless drawing; os.environ is left alone, so later Qt apps are not affected
        app = QtWidgets.QApplication(["lfm-studio bench", "-platform", "offscreen"])
    pg.setConfigOptions(antialias=True, background="w", foreground="k")
    columns = min(2, max(1, len(results)))
    rows = math.ceil(len(results) / columns)
    layout = pg.GraphicsLayoutWidget()
    layout.resize(PANEL_SIZE[0] * columns, PANEL_SIZE[1] * rows)
    for index, result in enumerate(results):
        plot = layout.addPlot(
            row=index // columns, col=index % columns, title=f"{result.case} ({result.kind})"
        )
        plot.setLogMode(x=True, y=True)
        plot.setLabel("bottom", "time (s)")
        plot.setLabel("left", "worst-depth relative PSF error")
        plot.showGrid(x=True, y=True, alpha=0.3)
        points = _points(result)
        for side, values in (("bottom", [p[0] for p in points]), ("left", [p[1] for p in points])):
            axis = plot.getAxis(side)
            axis.enableAutoSIPrefix(False)  # plain numbers, not "x0.001" with scaled labels
            axis.setTicks(log_ticks(min(values), max(values)))
        if points:  # room on the right for the labels of the slowest points
            lo, hi = min(p[0] for p in points), max(p[0] for p in points)
            plot.setXRange(
                math.log10(lo) - 0.05, math.log10(hi) + 0.25 * max(math.log10(hi / lo), 0.4), padding=0
            )
        plot.plot([p[0] for p in points], [p[1] for p in points], pen=None, symbol="o", symbolSize=7,
                  symbolBrush=(120, 120, 120), symbolPen=None)  # fmt: skip
        front = sorted((p for p in points if p[3]), key=lambda p: p[0])
        plot.plot([p[0] for p in front], [p[1] for p in front], pen=pg.mkPen((220, 40, 40), width=2),
                  symbol="o", symbolSize=8, symbolBrush=(220, 40, 40), symbolPen=None)  # fmt: skip
        presets = [p for p in points if p[4]]
        plot.plot([p[0] for p in presets], [p[1] for p in presets], pen=None, symbol="star", symbolSize=16,
                  symbolBrush=(30, 90, 220), symbolPen="k")  # fmt: skip
        font = QtGui.QFont()
        font.setPointSize(7)
        for t, e, label, _, is_preset in points:
            text = pg.TextItem(label, color=(30, 90, 220) if is_preset else (60, 60, 60), anchor=(0, 1))
            text.setFont(font)
            text.setPos(math.log10(t), math.log10(e))
            plot.addItem(text)
    width, height = PANEL_SIZE[0] * columns, PANEL_SIZE[1] * rows
    layout.ci.setGeometry(QtCore.QRectF(0, 0, width, height))  # a hidden widget is never laid out
    app.processEvents()
    exporter = exporters.ImageExporter(layout.ci)
    exporter.parameters()["width"] = width
    image = exporter.export(toBytes=True)
    buffer = QtCore.QBuffer()
    buffer.open(QtCore.QIODevice.OpenModeFlag.WriteOnly)
    image.save(buffer, "PNG")
    data = bytes(buffer.data())
    layout.close()
    return data


def log_ticks(lo: float, hi: float) -> list[list[tuple[float, str]]]:
    """pyqtgraph ticks (positions in log10) for values in ``[lo, hi]``: ``1, 2, 5 x 10^k`` labelled
    when the range spans at most three decades, decades only (with unlabelled 2 and 5) beyond."""
    if not (lo > 0 and hi >= lo):
        return [[], []]
    first, last = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    dense = last - first <= 3
    major, minor = [], []
    for k in range(first, last + 1):
        for m in (1, 2, 5):
            value = m * 10.0**k
            if not lo / 1.5 <= value <= hi * 1.5:
                continue
            tick = (math.log10(value), f"{value:g}")
            (major if m == 1 or dense else minor).append(tick if m == 1 or dense else (tick[0], ""))
    return [major, minor]


def _render_raster(results: list[CaseResult]) -> bytes:
    """A plain PNG: one panel per case, grey points, red front, blue presets (no text)."""
    w, h = PANEL_SIZE
    width, height = w, h * max(1, len(results))
    pixels = bytearray(b"\xff" * (width * height * 3))

    def dot(x: int, y: int, color: tuple[int, int, int], r: int) -> None:
        for yy in range(max(0, y - r), min(height, y + r + 1)):
            for xx in range(max(0, x - r), min(width, x + r + 1)):
                i = 3 * (yy * width + xx)
                pixels[i : i + 3] = bytes(color)

    for k, result in enumerate(results):
        points = _points(result)
        if not points:
            continue
        lx = [math.log10(p[0]) for p in points]
        ly = [math.log10(p[1]) for p in points]
        x0, x1 = min(lx) - 0.1, max(lx) + 0.1
        y0, y1 = min(ly) - 0.1, max(ly) + 0.1

        def at(t: float, e: float, k: int = k, x0=x0, x1=x1, y0=y0, y1=y1) -> tuple[int, int]:
            px = 40 + (math.log10(t) - x0) / (x1 - x0) * (w - 80)
            py = k * h + h - 40 - (math.log10(e) - y0) / (y1 - y0) * (h - 80)
            return int(px), int(py)

        front = sorted((p for p in points if p[3]), key=lambda p: p[0])
        for a, b in itertools.pairwise(front):
            (xa, ya), (xb, yb) = at(a[0], a[1]), at(b[0], b[1])
            steps = max(abs(xb - xa), abs(yb - ya), 1)
            for s in range(steps + 1):
                dot(xa + (xb - xa) * s // steps, ya + (yb - ya) * s // steps, (220, 40, 40), 0)
        for t, e, _, on_front, is_preset in points:
            color = (30, 90, 220) if is_preset else (220, 40, 40) if on_front else (120, 120, 120)
            dot(*at(t, e), color, 5 if is_preset else 3)
    raw = b"".join(b"\x00" + bytes(pixels[3 * width * y : 3 * width * (y + 1)]) for y in range(height))

    def chunk(tag: bytes, body: bytes) -> bytes:
        return (
            struct.pack(">I", len(body)) + tag + body + struct.pack(">I", zlib.crc32(tag + body) & 0xFFFFFFFF)
        )

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(raw, 6))
        + chunk(b"IEND", b"")
    )
