"""The launch path: the studio window opens and closes cleanly."""

from __future__ import annotations

from lfm_studio.ui.placeholder_window import PlaceholderWindow


def test_placeholder_window_shows_requested_design(qtbot):
    window = PlaceholderWindow(design="xlfm_like")
    qtbot.addWidget(window)
    window.show()
    qtbot.waitExposed(window)
    assert window.windowTitle() == "lfm_studio"
    assert "xlfm_like" in window.centralWidget().text()
