"""The studio's "Optimise" dock, in the window ``lfm-studio gui`` builds: a tiny grid on a closed-form
objective runs to the candidate the closed form predicts (infeasible ones recorded with their reason),
cancel keeps the candidates shown and starts no more, a double-click loads a candidate, Compare shows both
designs' metrics and PSFs, a study file is resumed without re-evaluating, bad settings are refused by name."""

from __future__ import annotations

import re
import threading

import numpy as np
import pytest
from qtpy.QtCore import QSettings, Qt
from qtpy.QtGui import QFontMetrics
from qtpy.QtWidgets import QDockWidget

from lfm_studio.engine.design import list_presets, load_preset
from lfm_studio.engine.optimize import DesignSpace, Parameter
from lfm_studio.engine.optimize import objectives as objectives_module
from lfm_studio.engine.optimize.objectives import ClosedForm
from lfm_studio.engine.performance import closed_form_metrics
from lfm_studio.ui.app import build_studio
from lfm_studio.ui.edits import apply_changes
from lfm_studio.ui.main_window import DEFAULT_SIZE
from lfm_studio.ui.optimise_dock import JOB_NAME
from lfm_studio.ui.optimise_model import freeable_fields
from tests.ui.standins import FakeMLAEditor, FakePSFViewer, small_fourier_design

TIMEOUT_MS = 60_000
RELAY = "relay.focal_length_mm"
RELAYS_MM = (60.0, 70.0, 80.0, 90.0)  # 60 and 70 mm: sub-images leave the 256^2 sensor (infeasible)


@pytest.fixture
def window(small_studio):
    return small_studio


def _lateral_um(design, relay_mm):
    """Independent reference: the closed form of the design edited by the parameter panel's path."""
    return closed_form_metrics(apply_changes(design, {RELAY: relay_mm})).lateral_resolution * 1e6


def _run_grid(qtbot, dock, objectives=("lateral_resolution",)):
    dock.free(RELAY, RELAYS_MM[0], RELAYS_MM[-1], len(RELAYS_MM))
    dock.set_objectives(list(objectives))
    dock.sampler.setCurrentText("grid")
    dock.budget.setValue(len(RELAYS_MM))
    dock.run_button.click()


def test_the_dock_is_in_the_window_and_the_view_menu(window):
    docks = {d.windowTitle(): d for d in window.findChildren(QDockWidget)}
    assert docks["Optimise"].widget() is window.optimise
    view = next(m for m in window.menuBar().actions() if m.text() == "&View").menu()
    assert "Optimise" in [a.text() for a in view.actions()]
    paths = [
        window.optimise.parameters.item(r, 0).data(Qt.ItemDataRole.UserRole)
        for r in range(window.optimise.parameters.rowCount())
    ]
    assert "objective.numerical_aperture" in paths and RELAY in paths  # the parameter panel's fields
    assert "mla.lenslets[*].focal_length_mm" in paths and "mla.lenslets[3].center_um[1]" in paths  # the MLA's


def test_a_tiny_grid_finds_the_candidate_the_closed_form_predicts(qtbot, window):
    dock, design = window.optimise, window.state.design
    _run_grid(qtbot, dock)
    assert dock.cancel_button.isEnabled() and not dock.run_button.isEnabled()
    qtbot.waitUntil(lambda: dock.message.text().startswith("Done"), timeout=TIMEOUT_MS)
    assert window.state.job(JOB_NAME).state == "done"
    rows = dock.rows
    assert [r.params[RELAY] for r in rows] == pytest.approx(RELAYS_MM)
    # Short relays magnify the sub-images beyond the 256^2 sensor: refused with their reason, not scored.
    assert [r.reason for r in rows[:2]] == ["sub_image_off_sensor"] * 2
    assert all(r.feasible for r in rows[2:])
    for row in rows[2:]:
        assert row.values["lateral_resolution"] == pytest.approx(
            _lateral_um(design, row.params[RELAY]), rel=1e-9
        )
    # Sampling-limited: the sample pixel grows with the relay focal length, so the shortest feasible relay wins.
    assert rows[3].values["lateral_resolution"] / rows[2].values["lateral_resolution"] == pytest.approx(
        90 / 80
    )
    assert dock.best() is rows[2]
    # The table shows every candidate (infeasible ones with their reason); the plot draws only scores
    # (infeasible ones were drawn at the best feasible value, as if they had scored it) and counts the rest.
    table = [[dock.table.item(r, c).text() for c in range(dock.table.columnCount())] for r in range(4)]
    assert [t[-1] for t in table] == ["no: sub_image_off_sensor"] * 2 + ["yes"] * 2
    assert dock.table.horizontalHeaderItem(2).text() == "lateral_resolution (µm)"
    plot = dock.plot.getPlotItem()
    assert plot.getAxis("left").labelText == "µm"  # the name is in the title ("eral_resolution (um)" was cut)
    assert "lateral_resolution" in plot.titleLabel.text and "2 infeasible, not scored" in plot.titleLabel.text
    assert list(dock.feasible_dots.getData()[0]) == [2, 3]
    assert list(dock.best_curve.getData()[1]) == pytest.approx([rows[2].values["lateral_resolution"]] * 2)


def test_a_run_without_a_feasible_candidate_does_not_invite_a_load(qtbot, window):
    dock = window.optimise
    dock.free(RELAY, 60.0, 70.0, 2)  # both sub-image patterns leave the sensor
    dock.set_objectives(["lateral_resolution"])
    dock.sampler.setCurrentText("grid")
    dock.budget.setValue(2)
    dock.run_button.click()
    qtbot.waitUntil(lambda: dock.message.text().startswith("Done"), timeout=TIMEOUT_MS)
    assert dock.best() is None and "none feasible" in dock.message.text()
    assert "double-click" not in dock.message.text()
    assert dock.feasible_dots.getData()[0] is None or len(dock.feasible_dots.getData()[0]) == 0


def test_double_click_loads_a_candidate_and_an_infeasible_one_is_refused(qtbot, window):
    dock, state = window.optimise, window.state
    _run_grid(qtbot, dock)
    qtbot.waitUntil(lambda: dock.message.text().startswith("Done"), timeout=TIMEOUT_MS)
    before = state.design
    dock.table.cellDoubleClicked.emit(0, 0)  # 60 mm: infeasible, has no design
    assert state.design is before and "infeasible" in dock.message.text()
    dock.table.cellDoubleClicked.emit(3, 0)
    assert state.design.relay.focal_length_mm == pytest.approx(90.0)
    assert state.design.mla == before.mla and state.dirty
    assert window.parameter_panel.inputs[RELAY].value() == pytest.approx(90.0)  # the panel shows it


def test_compare_shows_both_candidates_metrics(qtbot, window):
    dock, design = window.optimise, window.state.design
    _run_grid(qtbot, dock)
    qtbot.waitUntil(lambda: dock.message.text().startswith("Done"), timeout=TIMEOUT_MS)
    dock.table.selectRow(2)
    dock.table.selectionModel().select(
        dock.table.model().index(3, 0), dock.table.selectionModel().SelectionFlag.Select
        | dock.table.selectionModel().SelectionFlag.Rows,
    )  # fmt: skip
    assert [r.number for r in dock.selected_rows()] == [2, 3]
    dock.compare_button.click()
    assert dock.tabs.currentIndex() == 1
    table = {row[0]: row[1:] for row in dock.compare_rows()}
    a, b = (float(re.match(r"[\d.]+", v).group()) for v in table["Lateral resolution"])
    assert a == pytest.approx(_lateral_um(design, 80.0), rel=1e-3)
    assert b == pytest.approx(_lateral_um(design, 90.0), rel=1e-3)
    requirement_rows = [k for k in table if k.startswith("Requirement:")]
    assert len(requirement_rows) == 4  # FoV, DoF, lateral and axial resolution of the zebrafish spec
    assert all(v.split()[0] in ("PASS", "FAIL", "?") for k in requirement_rows for v in table[k])
    assert table["Requirements overall"] == ("fails some", "fails some")  # a 50 um field of view
    # Their PSFs, side by side (a quick preview job): an on-axis point focuses under each lenslet's centre.
    qtbot.waitUntil(lambda: all(i.image is not None for i in dock.psf_images), timeout=TIMEOUT_MS)
    a_img, b_img = (i.image.T for i in dock.psf_images)
    assert a_img.shape == b_img.shape == (256, 256)  # the whole 256^2 sensor (under the 512 px crop)
    assert a_img.max() == pytest.approx(1.0) and b_img.max() == pytest.approx(1.0)
    centre_px = np.hypot(600.0, 600.0) / design.camera.pixel_pitch_um  # lenslets at (+-600, +-600) um
    for img in (a_img, b_img):
        bright = np.argwhere(img > 0.5) - (np.array(img.shape) - 1) / 2
        assert len(bright) >= 4 and np.hypot(*bright.T) == pytest.approx(centre_px, abs=3.0)


def test_compare_shows_every_value_whole_at_the_default_window_size(qtbot, window):
    """The values and headers are not elided ("2.… µm", "andida"): each column is as wide as its text."""
    dock = window.optimise
    assert (window.width(), window.height()) == DEFAULT_SIZE
    window.findChild(QDockWidget, "Optimise").raise_()
    _run_grid(qtbot, dock)
    qtbot.waitUntil(lambda: dock.message.text().startswith("Done"), timeout=TIMEOUT_MS)
    dock.table.selectRow(2)
    dock.table.selectionModel().select(
        dock.table.model().index(3, 0), dock.table.selectionModel().SelectionFlag.Select
        | dock.table.selectionModel().SelectionFlag.Rows,
    )  # fmt: skip
    dock.compare_button.click()
    table = dock.compare_table
    metrics = QFontMetrics(table.font())
    header = table.horizontalHeader()
    for c in range(table.columnCount()):
        texts = [table.item(r, c).text() for r in range(table.rowCount())]
        texts.append(table.horizontalHeaderItem(c).text())
        widest = max(metrics.horizontalAdvance(t) for t in texts)
        assert table.columnWidth(c) >= widest, (c, max(texts, key=metrics.horizontalAdvance))
    assert header.length() <= table.viewport().width()  # no column hidden behind a horizontal scroll


def test_cancel_mid_run_keeps_the_candidates_evaluated(qtbot, tmp_path, monkeypatch):
    release, calls = threading.Event(), []

    class Gated(ClosedForm):
        def __call__(self, candidate):  # the second candidate waits until the test has pressed Cancel
            calls.append(1)
            if len(calls) == 2:
                release.wait(30)
            return super().__call__(candidate)

    factory = (lambda options: Gated("lateral_resolution"), "test: gated closed form")
    monkeypatch.setitem(objectives_module._REGISTRY, "lateral_resolution", factory)
    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    win = build_studio(
        small_fourier_design(), settings=settings, debounce_ms=600_000,
        editor_factory=lambda d: FakeMLAEditor(d.mla.lenslets), viewer_factory=FakePSFViewer,
    )  # fmt: skip
    dock = win.optimise
    dock.free(RELAY, 80.0, 110.0, 4)  # four feasible candidates
    dock.set_objectives(["lateral_resolution"])
    dock.budget.setValue(4)
    dock.run_button.click()
    qtbot.waitUntil(
        lambda: len(calls) == 2 and len(dock.rows) == 1, timeout=TIMEOUT_MS
    )  # 1st shown, 2nd held
    dock.cancel_button.click()
    release.set()
    qtbot.waitUntil(lambda: win.state.job(JOB_NAME).state == "cancelled", timeout=TIMEOUT_MS)
    # The candidate shown stays; the one in flight finished after Cancel (dropped, as the runner drops
    # every delivery of a cancelled job) and no third one started.
    assert [r.number for r in dock.rows] == [0] and dock.table.rowCount() == 1
    assert len(calls) == 2 and dock.message.text().startswith("Cancelled")
    assert dock.run_button.isEnabled() and not dock.cancel_button.isEnabled()
    with qtbot.waitSignal(win.destroyed, timeout=TIMEOUT_MS):
        assert win.close()


def test_bad_settings_are_refused_with_the_parameter_named(qtbot, window):
    dock = window.optimise
    dock.run_button.click()  # nothing freed
    assert "no parameter is freed" in dock.message.text() and not dock.is_running()
    dock.free(RELAY, 90.0, 80.0, 3)
    dock.run_button.click()
    assert RELAY in dock.message.text() and "low must be <= high" in dock.message.text()
    dock.free(RELAY, 80.0, 90.0, 3)
    dock.parameters.item(dock.parameter_row(RELAY), 5).setText("two")
    dock.run_button.click()
    assert f"points of {RELAY} must be a number" in dock.message.text() and not dock.is_running()


def test_a_study_file_stores_the_candidates_and_resume_evaluates_only_new_ones(
    qtbot, window, monkeypatch, tmp_path
):
    calls = []

    class Counted(ClosedForm):
        def __call__(self, candidate):
            calls.append(candidate.design.relay.focal_length_mm)
            return super().__call__(candidate)

    factory = (lambda options: Counted("lateral_resolution"), "test: counted closed form")
    monkeypatch.setitem(objectives_module._REGISTRY, "lateral_resolution", factory)
    dock = window.optimise
    dock.study_path.setText(str(tmp_path / "study.db"))
    dock.free(RELAY, 80.0, 110.0, 4)
    dock.set_objectives(["lateral_resolution"])
    dock.budget.setValue(2)
    dock.run_button.click()
    qtbot.waitUntil(lambda: window.state.job(JOB_NAME).state == "done", timeout=TIMEOUT_MS)
    assert [r.params[RELAY] for r in dock.rows] == pytest.approx([80.0, 90.0]) and calls == [80.0, 90.0]
    dock.run_button.click()  # the study exists: refused unless resumed
    qtbot.waitUntil(lambda: window.state.job(JOB_NAME).state == "failed", timeout=TIMEOUT_MS)
    assert "already exists" in dock.message.text() and len(calls) == 2
    dock.resume.setChecked(True)
    dock.budget.setValue(4)
    dock.run_button.click()
    qtbot.waitUntil(lambda: window.state.job(JOB_NAME).state == "done", timeout=TIMEOUT_MS)
    assert [r.params[RELAY] for r in dock.rows] == pytest.approx(
        [80.0, 90.0, 100.0, 110.0]
    )  # stored ones too
    assert calls == [80.0, 90.0, 100.0, 110.0]  # the stored candidates were not evaluated again


@pytest.mark.parametrize("preset", list_presets())
def test_every_freeable_field_is_a_design_space_path_with_its_current_value(preset):
    design = load_preset(preset)
    fields = freeable_fields(design)
    space = DesignSpace(tuple(Parameter(f.path, low=f.value, high=f.value, points=1) for f in fields))
    stored = space.values_of(design)  # the engine's own reading of each path
    for f in fields:
        assert float(stored[f.path]) == pytest.approx(f.value), f.path
    paths = {f.path for f in fields}
    explicit = design.mla.model_dump().get("lenslets")  # a regular array lists none (freed by pitch)
    assert ("mla.pitch_um" in paths) == (not explicit)
    if explicit:
        count = len(explicit)
        assert {f"mla.lenslets[{count - 1}].center_um[0]", "mla.lenslets[*].focal_length_mm"} <= paths
    assert ("relay.focal_length_mm" in paths) == (design.kind == "fourier")


def test_the_zernike_terms_of_a_pupil_phase_mask_are_freeable():
    design = load_preset("xlfm_cong2017").updated(pupil_phase={"zernike_waves": {"4": 0.0, "11": -0.05}})
    fields = {f.path: f for f in freeable_fields(design)}
    assert fields["pupil_phase.zernike_waves.4"].value == 0.0
    assert fields["pupil_phase.zernike_waves.11"].value == -0.05
    assert fields["pupil_phase.zernike_waves.11"].unit == "waves"
    space = DesignSpace((Parameter("pupil_phase.zernike_waves.11", low=-0.1, high=0.1, points=3),))
    assert space.values_of(design) == {"pupil_phase.zernike_waves.11": -0.05}
    assert not any(
        p.startswith("pupil_phase") for p in (f.path for f in freeable_fields(load_preset("xlfm_cong2017")))
    )


def test_a_design_change_moves_an_unticked_range_but_keeps_a_ticked_one(window):
    """The table's Low/High follow the design's value unless the user ticked the row (their range)."""
    dock = window.optimise

    def cells(path):
        row = dock.parameter_row(path)
        return [float(dock.parameters.item(row, c).text()) for c in (2, 3, 4)]

    assert dock.parameters.horizontalHeaderItem(2).text() == "Now"
    dock.free(RELAY, 60.0, 90.0, 4)
    other = "objective.tube_lens_focal_length_mm"
    new_value = cells(other)[0] * 1.5  # outside the default +-10 % range around the old value
    design = apply_changes(window.state.design, {other: new_value, RELAY: 120.0})
    window.state.set_design(design)
    now, low, high = cells(other)
    assert now == pytest.approx(new_value, rel=1e-5)
    assert low <= now <= high  # the stale range around the old value is gone
    assert cells(RELAY)[1:] == [60.0, 90.0]  # ticked: the user's range stays, even if the value left it
    assert dock.parameters.item(dock.parameter_row(RELAY), 0).checkState() == Qt.CheckState.Checked


@pytest.mark.filterwarnings("ignore::lfm_studio.engine.optimize.study.StudyOptionsUncheckedWarning")
def test_resuming_a_study_stored_without_objective_options_says_they_were_not_checked(
    qtbot, window, tmp_path
):
    """A study from before objective options were stored still resumes; the message says the check was skipped."""
    import sqlite3

    dock = window.optimise
    path = tmp_path / "old.db"
    dock.study_path.setText(str(path))
    dock.free(RELAY, 80.0, 110.0, 4)
    dock.set_objectives(["lateral_resolution"])
    dock.budget.setValue(2)
    dock.run_button.click()
    qtbot.waitUntil(lambda: window.state.job(JOB_NAME).state == "done", timeout=TIMEOUT_MS)
    assert "could not check" not in dock.message.text()
    with sqlite3.connect(path) as db:  # as a study stored before the options were
        db.execute("DELETE FROM study_user_attributes WHERE key = 'objective_options'")
    dock.resume.setChecked(True)
    dock.budget.setValue(3)
    dock.run_button.click()  # the engine also warns, in the worker thread
    qtbot.waitUntil(lambda: window.state.job(JOB_NAME).state == "done", timeout=TIMEOUT_MS)
    assert len(dock.rows) == 3
    assert "Note: study 'lfm_study' was stored without its objective options" in dock.message.text()


def test_the_plot_key_is_above_the_axes_and_names_the_curves_drawn(qtbot, window):
    """A legend box inside the axes sat at the right, over the latest candidates."""
    import pyqtgraph as pg

    dock = window.optimise
    _run_grid(qtbot, dock)
    qtbot.waitUntil(lambda: dock.message.text().startswith("Done"), timeout=TIMEOUT_MS)
    item = dock.plot.getPlotItem()
    assert not [child for child in item.scene().items() if isinstance(child, pg.LegendItem)]
    title = item.titleLabel.text
    assert (
        "best so far" in title
        and "candidate" in title
        and title.index("against") < title.index("best so far")
    )
