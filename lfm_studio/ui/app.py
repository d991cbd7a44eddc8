"""Start the desktop studio.

Until the studio issue lands this opens a placeholder window that says what the
engine can do already and what comes next; the launch command stays the same.
"""

from __future__ import annotations

import os


def run_studio(design: str | None = None) -> int:
    """Open the studio window on ``design`` (a file or preset; default: bundled design).

    Returns the Qt event loop's exit status.
    """
    os.environ.setdefault("QT_API", "pyside6")
    os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")
    from qtpy.QtWidgets import QApplication

    from lfm_studio.ui.placeholder_window import PlaceholderWindow

    app = QApplication.instance() or QApplication([])
    window = PlaceholderWindow(design=design)
    window.show()
    return int(app.exec())
