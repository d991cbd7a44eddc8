"""Shared fixtures for the UI tests (pytest-qt under pytest-xvfb; ``QT_QPA_PLATFORM`` unset).

``qapp`` (session)
    From ``tests/conftest.py`` (:func:`lfm_studio.widgets.viewer.napari_embed.prepare_qt_app`).
``small_studio``
    The studio window as ``lfm-studio gui`` builds it, on the small test design, with stand-in
    MLA editor and PSF viewer and a long debounce (no PSF job during the test); closed after
    it, unsaved or not, and checked gone.
``close_napari_viewers`` (autouse)
    After each test, closes any napari ``QtViewer`` still alive (e.g. a window the test
    forgot to close, or a failing test) and runs the pending deletions, so napari's
    ``make_napari_viewer`` leak check in a later test does not fail because of an earlier
    one. It does not prove your widget cleans up: assert that in your test, e.g.
    ``assert napari_embed.live_qt_viewers() == 0`` after closing and :func:`collect_widgets`.
"""

from __future__ import annotations

import gc
import sys

import pytest

from lfm_studio.widgets.viewer import napari_embed

CLOSE_TIMEOUT_MS = 60_000


@pytest.fixture
def small_studio(qtbot, tmp_path):
    from qtpy.QtCore import QSettings
    from qtpy.QtWidgets import QApplication

    from lfm_studio.ui.app import build_studio
    from lfm_studio.ui.main_window import MainWindow
    from tests.ui.standins import FakeMLAEditor, FakePSFViewer, small_fourier_design

    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    win = build_studio(
        small_fourier_design(), settings=settings, debounce_ms=600_000,  # no PSF work during the test
        editor_factory=lambda d: FakeMLAEditor(d.mla.lenslets), viewer_factory=FakePSFViewer,
    )  # fmt: skip
    win.show()
    qtbot.waitExposed(win)
    yield win
    win.state.set_dirty(False)  # loaded candidates make the document unsaved: close without asking
    with qtbot.waitSignal(win.destroyed, timeout=CLOSE_TIMEOUT_MS):
        assert win.close()
    QApplication.sendPostedEvents(None, 0)
    gc.collect()
    assert [w for w in QApplication.topLevelWidgets() if isinstance(w, MainWindow)] == []


def collect_widgets() -> None:
    """Run pending ``deleteLater`` calls, then Python's garbage collector."""
    napari_embed.flush_deletions()
    gc.collect()


@pytest.fixture(autouse=True)
def close_napari_viewers():
    yield
    if "napari._qt.qt_viewer" not in sys.modules:
        return
    from napari.qt import QtViewer

    if not QtViewer._instances:
        return  # nothing alive: skip the (slow) garbage collection
    collect_widgets()  # closed viewers waiting for deleteLater / gc go first
    for qt_viewer in list(QtViewer._instances):
        napari_embed.close_qt_viewer(qt_viewer)  # skips viewers already closed
    collect_widgets()
