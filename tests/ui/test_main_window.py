"""The main window: opens on the default design, launch preview + cancel, unsaved-changes prompt on
close, no leaked widgets; with the real widgets, a non-blank napari render of a computed PSF."""

from __future__ import annotations

import gc
import importlib.util

import numpy as np
import pytest
from qtpy.QtCore import QSettings
from qtpy.QtWidgets import QApplication, QDockWidget, QMessageBox, QTabBar

from lfm_studio.engine.design import save_design
from lfm_studio.ui.app import DEFAULT_PRESET, _open, build_studio
from lfm_studio.ui.edits import apply_changes
from lfm_studio.ui.main_window import DEFAULT_SIZE, MainWindow
from tests.ui.standins import FakeMLAEditor, FakePSFViewer, small_fourier_design

TIMEOUT_MS = 30_000


@pytest.fixture
def settings(tmp_path):
    return QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)


def _fake_editor(design):
    return FakeMLAEditor(design.mla.lenslets)


def _open_window(qtbot, settings, design=None, **kwargs):
    kwargs.setdefault("editor_factory", _fake_editor)
    kwargs.setdefault("viewer_factory", FakePSFViewer)
    window = build_studio(design, settings=settings, **kwargs)
    window.show()
    qtbot.waitExposed(window)
    return window


def _close(qtbot, window):
    with qtbot.waitSignal(window.destroyed, timeout=TIMEOUT_MS):
        assert window.close()
    QApplication.sendPostedEvents(None, 0)
    gc.collect()
    leftovers = [w for w in QApplication.topLevelWidgets() if isinstance(w, MainWindow)]
    assert leftovers == []


def test_the_window_opens_on_the_default_design_and_closes_cleanly(qtbot, settings):
    window = _open_window(qtbot, settings)
    state = window.state
    assert DEFAULT_PRESET == "xlfm_cong2017"
    assert state.design.name == "XLFM after Cong et al. 2017"
    assert "XLFM after Cong et al. 2017" in window.windowTitle() and "not saved" in window.windowTitle()
    assert window.parameter_panel.inputs["objective.numerical_aperture"].value() == pytest.approx(1.0)
    assert window.editor.lenslets() == state.design.mla.lenslets  # 27 lenslets in the editor
    assert window.centralWidget() is window.viewer
    docks = {d.windowTitle() for d in window.findChildren(QDockWidget)}
    assert docks == {"Design parameters", "Design metrics vs larval zebrafish", "Plots", "MLA layout",
                     "Simulate and reconstruct", "Optimise", "Train"}  # fmt: skip
    assert [window.plot_tabs.tabText(i) for i in range(2)] == ["PSF profiles", "RL convergence"]
    tab_bars = [t for t in window.findChildren(QTabBar) if t.isVisible() and t.parent() is window]
    assert len(tab_bars) == 1  # the bottom dock group's, no stray copy (a Qt 6.12 glitch)
    assert [a.text() for a in window.menuBar().actions()] == ["&File", "&View"]
    assert window.requirements.rows()  # closed-form metrics at once, before any PSF
    viewer = window.viewer
    _close(qtbot, window)
    assert viewer.closed


def test_launch_starts_the_preview_and_cancel_stops_it(qtbot, settings):
    window = _open_window(qtbot, settings)
    state = window.state
    window.controller.start()
    qtbot.waitUntil(lambda: state.job("psf").total > 0, timeout=TIMEOUT_MS)  # lenslets are being computed
    assert state.job("psf").message.startswith("PSF preview (5 depths)")
    assert window.job_status.cancel_button.isEnabled() and window.job_status.progress.isVisible()
    window.job_status.cancel_button.click()
    qtbot.waitUntil(lambda: state.job("psf").state == "cancelled", timeout=TIMEOUT_MS)
    assert state.psf is None and "psf" in state.stale
    assert not window.job_status.cancel_button.isEnabled()
    _close(qtbot, window)


def test_closing_with_unsaved_changes_asks_first(qtbot, settings, monkeypatch, tmp_path):
    design = small_fourier_design()
    window = _open_window(qtbot, settings, design, debounce_ms=10_000)
    window.state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))
    # Qt draws "*" at the "[*]" placeholder while the window is modified.
    assert window.windowTitle().startswith("small FLFM test design (not saved)[*]")
    assert window.isWindowModified()
    answers = [QMessageBox.StandardButton.Cancel, QMessageBox.StandardButton.Discard]
    monkeypatch.setattr(QMessageBox, "question", lambda *a, **k: answers.pop(0))
    assert not window.close()
    assert window.isVisible() and len(answers) == 1
    _close(qtbot, window)
    assert answers == []


def test_closing_with_a_refused_value_on_screen_asks_first(qtbot, settings, monkeypatch):
    from qtpy.QtCore import Qt
    from qtpy.QtTest import QTest

    window = _open_window(qtbot, settings, small_fourier_design(), debounce_ms=10_000)
    state = window.state
    assert not window.isWindowModified()
    box = window.parameter_panel.inputs["objective.numerical_aperture"].boxes[0]
    box.setFocus()
    box.selectAll()
    QTest.keyClicks(box, "2.5")  # refused: an air objective
    QTest.keyClick(box, Qt.Key.Key_Return)
    assert "objective.numerical_aperture" in state.errors and not state.dirty
    assert window.isWindowModified()  # unsaved input: the title's "*"
    questions, answers = [], [QMessageBox.StandardButton.Cancel, QMessageBox.StandardButton.Discard]

    def question(parent, title, text, *args, **kwargs):
        questions.append(text)
        return answers.pop(0)

    monkeypatch.setattr(QMessageBox, "question", question)
    assert not window.close()
    assert window.isVisible() and box.text().startswith("2.5")  # Cancel: the typed value is still there
    assert questions == ["1 field shows a refused value that will be lost: Numerical aperture. Discard it?"]
    _close(qtbot, window)  # Discard
    assert answers == []


def test_the_command_line_argument_opens_a_preset_or_a_file(tmp_path):
    design, path = _open("flfm_guo2019")
    assert design.name.startswith("FLFM") and path is None
    small = small_fourier_design()
    save_design(small, tmp_path / "small.json")
    design, path = _open(str(tmp_path / "small.json"))
    assert design == small and path == (tmp_path / "small.json").resolve()


@pytest.mark.skipif(
    importlib.util.find_spec("lfm_studio.widgets.psf_viewer") is None
    or importlib.util.find_spec("lfm_studio.widgets.mla_editor") is None,
    reason="the real MLA editor / PSF viewer widgets are not installed",
)
def test_real_widgets_show_a_non_blank_napari_render_and_edits_recompute_one_lenslet(qtbot, settings):
    from lfm_studio.ui.widget_factories import warm_up_viewer
    from lfm_studio.widgets.viewer import napari_embed

    reason = napari_embed.napari_unavailable_reason()
    if reason is not None:
        pytest.skip(f"napari cannot render here: {reason}")
    design = small_fourier_design()
    window = build_studio(design, settings=settings, preview=False, debounce_ms=10)
    window.show()
    qtbot.waitExposed(window)
    state, viewer, editor = window.state, window.viewer, window.editor
    assert viewer.backend == "napari"
    warm_up_viewer(viewer)  # what run_studio does before showing the window: leaves no layer behind
    assert viewer.layer_names() == []
    window.controller.start()
    qtbot.waitUntil(lambda: state.psf is not None, timeout=TIMEOUT_MS)
    assert "PSF" in viewer.layer_names()
    qtbot.wait(200)
    shot = np.asarray(viewer.screenshot())
    assert shot.ndim == 3 and shot[..., :3].std() > 1.0  # not a blank canvas
    # The real editor commits a lenslet: only that lenslet is recomputed.
    assert tuple(editor.lenslets()) == design.mla.lenslets
    first = state.psf
    lenslets = list(editor.lenslets())
    lenslets[1] = lenslets[1].model_copy(update={"focal_length_mm": 17.5})
    editor.lensletsCommitted.emit(tuple(lenslets))
    qtbot.waitUntil(lambda: state.psf is not first and "psf" not in state.stale, timeout=TIMEOUT_MS)
    assert state.psf.lenslets_computed == (1,)
    state.set_dirty(False)
    _close(qtbot, window)
    napari_embed.flush_deletions()
    gc.collect()
    assert napari_embed.live_qt_viewers() == 0


def test_the_requirements_table_fits_its_dock_at_the_default_size(small_studio):
    """Its Value column was cut off at 1600x1000 (a long criterion made the first column too wide)."""
    table = small_studio.requirements.table
    assert table.rowCount() and (small_studio.width(), small_studio.height()) == DEFAULT_SIZE
    assert table.horizontalHeader().length() <= table.viewport().width()
