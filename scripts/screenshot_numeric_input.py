"""Screenshots of the parameter panel taking typed numbers: ``0,5`` read as 0.5, ``nan`` refused in place.

Usage (needs a display; headless: ``xvfb-run -a -s "-screen 0 1600x1000x24"``)::

    python scripts/screenshot_numeric_input.py OUTPUT_DIR [--locale C]

Writes ``input_comma.png`` (``0,5`` typed into the read noise, Enter: the design holds 0.5)
and ``input_nan.png`` (``nan`` typed into the tube lens focal length, Enter: red border, the
reason under the field, the design unchanged). A caption on top states the value in force,
read back from the design.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

CASES = (
    ("input_comma.png", "camera.read_noise_e", "0,5"),
    ("input_nan.png", "objective.tube_lens_focal_length_mm", "nan"),
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", type=Path, help="folder for the PNG files")
    parser.add_argument("--locale", default="C", help="QLocale name (C, de_DE, ...)")
    args = parser.parse_args(argv)
    os.environ.setdefault("QT_API", "pyside6")
    os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")
    from qtpy.QtCore import QLocale, Qt
    from qtpy.QtTest import QTest
    from qtpy.QtWidgets import QApplication, QLabel, QVBoxLayout, QWidget

    from lfm_studio.engine.design import load_preset
    from lfm_studio.ui.app import DEFAULT_PRESET
    from lfm_studio.ui.edits import read_path
    from lfm_studio.ui.parameter_panel import ParameterPanel
    from lfm_studio.ui.state import StudioState

    app = QApplication.instance() or QApplication(sys.argv[:1])
    QLocale.setDefault(QLocale(args.locale))
    args.output.mkdir(parents=True, exist_ok=True)
    ok = True
    for name, path, text in CASES:
        state = StudioState(load_preset(DEFAULT_PRESET))
        window = QWidget()
        layout = QVBoxLayout(window)
        caption = QLabel(window)
        caption.setWordWrap(True)
        panel = ParameterPanel(state, window)
        layout.addWidget(caption)
        layout.addWidget(panel, 1)
        window.resize(430, 980)
        window.show()
        box = panel.inputs[path].boxes[0]
        panel.ensureWidgetVisible(box)
        before = read_path(state.design, path)
        box.setFocus()
        box.selectAll()
        QTest.keyClicks(box, text)
        QTest.keyClick(box, Qt.Key.Key_Return)
        after = read_path(state.design, path)
        verdict = "refused, the value before stays in force" if box.error() else "taken"
        caption.setText(
            f"<b>Typed '{text}' + Enter into “{panel.inputs[path].spec.label}”</b> (locale {args.locale}): "
            f"{verdict}.<br>Design value in force: {before} → <b>{after}</b>"
        )
        for _ in range(20):
            app.processEvents()
        panel.ensureWidgetVisible(panel.error_labels[path])
        app.processEvents()
        target = args.output / name
        saved = window.grab().save(str(target))
        ok &= saved
        print(f"wrote {target}: {before} -> {after}" if saved else f"could not write {target}")
        panel.disconnect_state()
        window.close()
        window.deleteLater()
        app.processEvents()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
