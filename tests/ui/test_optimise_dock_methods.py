"""The Optimise dock's other methods, driven as a user does: Algorithm 2 finds the MLA layout the engine
finds (non-overlapping lenslets, loadable), a gradient PSF-engineering run lowers its objective and its
final design loads, an end-to-end run reports the held-out loss, each method shows only its options,
bad option values are refused by name, and Cancel keeps the previous results."""

from __future__ import annotations

import itertools
import math
import re
import threading
import warnings

import pytest

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optimize import (
    DesignSpace,
    Parameter,
    objective_named,
    optimize_psf,
    run_algorithm2_study,
)
from lfm_studio.engine.optimize import objectives as objectives_module
from lfm_studio.engine.optimize.candidate import EvaluationSettings
from lfm_studio.engine.optimize.constraints import REASONS
from lfm_studio.engine.optimize.crop import auto_crop
from lfm_studio.engine.optimize.objectives import CRB_PHOTONS, ClosedForm, score_options
from lfm_studio.engine.optimize.task_score import TASK_PHOTONS
from lfm_studio.ui.optimise_dock import JOB_NAME
from lfm_studio.ui.optimise_model import (
    METHODS,
    FreeParameter,
    GradientRequest,
    build_objective,
    run_gradient,
)
from tests.ui.standins import small_fourier_design

pytest.importorskip("optuna")

TIMEOUT_MS = 120_000
FOCAL, DISTANCE = "mla.lenslets[*].focal_length_mm", "mla_to_camera_distance_mm"
BOUNDS = {FOCAL: (12.0, 24.0), DISTANCE: (14.0, 20.0)}
POOR = {FOCAL: 22.0, DISTANCE: 15.0}  # out of focus: 22 mm lenslets with the camera 15 mm behind them
SPACE = DesignSpace(tuple(Parameter(p, *b) for p, b in BOUNDS.items()))
CELL_UM = 1000.0  # the FLFM preset's pupil at the MLA is 3 cells of 1 mm across: 9 layouts


def _quiet(build):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        return build()


@pytest.fixture
def window(small_studio):
    return small_studio


def _done(qtbot, window):
    qtbot.waitUntil(lambda: window.state.job(JOB_NAME).state != "running", timeout=TIMEOUT_MS)
    assert window.state.job(JOB_NAME).state == "done", window.optimise.message.text()


def _algorithm2(qtbot, window, objective="lateral_resolution"):
    dock = window.optimise
    window.state.set_design(_quiet(lambda: load_preset("flfm_guo2019")))
    dock.set_method("algorithm2")
    dock.a2_objective.setCurrentText(objective)
    dock.a2_min_lenslet.setText(f"{CELL_UM:g}")
    dock.run_button.click()


def _poor_start(window):
    window.state.set_design(_quiet(lambda: SPACE.apply(window.state.design, POOR)))


def _label(dock, path):
    """The free-parameter table's label of ``path``."""
    return dock.parameters.item(dock.parameter_row(path), 1).text()


def _free_focus(dock):
    for path, (low, high) in BOUNDS.items():
        dock.free(path, low, high, 3)


def test_each_method_shows_only_its_own_options(window):
    dock = window.optimise
    assert dock.method_key() == "grid" and [dock.method.itemData(i) for i in range(4)] == list(METHODS)
    boxes = {
        "grid": dock.grid_box, "algorithm2": dock.algorithm2_box, "gradient": dock.gradient_box,
        "gradient-psf": dock.psf_box, "gradient-end-to-end": dock.e2e_box, "crb": dock.crb_box,
    }  # fmt: skip
    for method in METHODS:
        dock.set_method(method)
        shown = {k for k, box in boxes.items() if not box.isHidden()}
        expected = {method} | ({"gradient"} if method.startswith("gradient") else {"crb"})
        assert shown == expected, method
        assert dock.parameters.isHidden() == (method == "algorithm2")
        assert dock.parameters.isColumnHidden(5) == method.startswith("gradient")  # no grid points
    # The CLI's defaults (lfm-studio optimize), each option with a tooltip giving what it does
    assert (dock.g_steps.value(), dock.g_lr.value(), dock.g_optimizer.currentText()) == (20, 0.05, "adam")
    assert (dock.g_schedule.currentText(), dock.g_objective.currentText()) == ("constant", "axial_crb")
    # The crop: the CLI's automatic one (the small test sensor is not larger than 256 px: the whole sensor, 0)
    assert dock.g_crop.value() == dock.a2_crop.value() == (auto_crop(window.state.design) or 0) == 0
    assert (dock.e_lr.value(), dock.e_iterations.value(), dock.e_batch.value(), dock.e_held_out.value()) == (
        0.01, 4, 2, 4,
    )  # fmt: skip
    # axial_crb at the CLI's default photons per emitter, the task loss at its photons per image (walk4 #3)
    assert dock.g_photons.value() == dock.c_photons.value() == CRB_PHOTONS == 1000.0
    assert (
        dock.e_photons.value() == TASK_PHOTONS
        and dock.g_background.value() == dock.c_background.value() == 1.0
    )
    assert dock.a2_symmetry.currentText() == "none" and dock.a2_sizes.text() == ""
    assert "µm" in dock.a2_min_lenslet.toolTip() and "--min-lenslet-um" in dock.a2_min_lenslet.toolTip()
    for widget in (dock.g_lr, dock.g_steps, dock.g_schedule, dock.e_batch, dock.a2_symmetry, dock.a2_sizes):
        assert "CLI --" in widget.toolTip()
    assert "range" in dock.g_lr.toolTip() and "px" in dock.g_crop.toolTip()


def _no_overlaps(lenslets):
    """Independent check of Algorithm 2's constraint: no two lenslet apertures overlap (they may touch)."""
    for a, b in itertools.combinations(lenslets, 2):
        gap = math.dist(a.center_um, b.center_um) - (a.aperture_diameter_um + b.aperture_diameter_um) / 2
        assert gap >= -1e-6, (a, b)


def test_algorithm2_finds_the_engines_layout_without_overlaps_and_it_loads(qtbot, window, tmp_path):
    _algorithm2(qtbot, window)
    dock, state = window.optimise, window.state
    base = state.design
    _done(qtbot, window)
    # The engine's own search on the same design, independently of the dock: the same best layout.
    objective = objective_named("lateral_resolution")
    reference, _ = run_algorithm2_study(base, objective, str(tmp_path / "ref.db"), min_lenslet_um=CELL_UM)
    assert reference.score < reference.history[0]  # a merge improved on the all-minimum start
    best = dock.best()
    assert best is not None and best.number == dock.chosen and best.note == "accepted"
    assert best.values["lateral_resolution"] == pytest.approx(reference.score, rel=1e-12)
    assert [r.number for r in dock.rows] == list(range(len(dock.rows))) and len(dock.rows) == 9
    infeasible = [r for r in dock.rows if not r.feasible]
    assert infeasible and all(r.reason == "layout_refused" for r in infeasible)  # cells outside the pupil
    assert f"{len(reference.blocks)} lenslets" in dock.message.text() and dock.message.text().startswith(
        "Done"
    )
    assert len(reference.blocks) >= 2 and "no depth information" not in dock.message.text()
    # the table: the block merged, the base, the lenslet count, the score, "yes (accepted)" for the best
    table = {dock.table.horizontalHeaderItem(c).text(): c for c in range(dock.table.columnCount())}
    row = dock.rows.index(best)
    assert dock.table.item(row, table["lenslets"]).text() == str(len(reference.blocks))
    assert dock.table.item(row, table["Feasible / reason"]).text() == "yes (accepted)"
    assert list(dock.plot.getPlotItem().getAxis("bottom").labelText.split()) == ["layout", "considered"]
    # Load it: the design in force has the layout found, no two lenslets overlap, all inside the pupil
    dock.table.cellDoubleClicked.emit(row, 0)
    lenslets = state.design.mla.lenslets
    assert len(lenslets) == len(reference.blocks) == reference.design.mla.count
    assert sorted(lens.center_um for lens in lenslets) == sorted(
        lens.center_um for lens in reference.design.mla.lenslets
    )
    _no_overlaps(lenslets)
    radius_um = base.pupil_diameter_at_mla * 1e6 / 2
    assert all(
        math.hypot(*lens.center_um) + lens.aperture_diameter_um / 2 <= radius_um + 1e-6 for lens in lenslets
    )
    assert state.dirty and "Loaded candidate" in dock.message.text()
    # two layouts side by side in the Compare tab: the start (5 lenslets) and the one found
    dock.compare(dock.rows[0], best)
    table = {row[0]: row[1:] for row in dock.compare_rows()}
    assert table["Number of views"] == ("5", str(len(reference.blocks)))
    qtbot.waitUntil(lambda: all(i.image is not None for i in dock.psf_images), timeout=TIMEOUT_MS)
    # an infeasible layout has no design
    before = state.design
    dock.table.cellDoubleClicked.emit(dock.rows.index(infeasible[0]), 0)
    assert state.design is before and "infeasible" in dock.message.text()


def test_algorithm2_notes_a_single_lenslet_best_layout_and_explains_the_refusal_codes(qtbot, window):
    """On the small FLFM, lateral resolution alone picks one big lenslet: the dock says that is no light field."""
    dock = window.optimise
    dock.set_method("algorithm2")
    dock.a2_objective.setCurrentText("lateral_resolution")  # the minimum lenslet size follows the design
    dock.run_button.click()
    _done(qtbot, window)
    best, text = dock.best(), dock.message.text()
    assert best is not None and best.params["lenslets"] == 1
    assert "1 lenslet," in text and "1 lenslets" not in text
    assert "no depth information" in text and "µm" in text and " um " not in text
    # every refused row says on hover what its code means; the column's header lists every code
    table = {dock.table.horizontalHeaderItem(c).text(): c for c in range(dock.table.columnCount())}
    column = table["Feasible / reason"]
    refused = [i for i, r in enumerate(dock.rows) if r.reason == "layout_refused"]
    assert refused
    for i in refused:
        assert dock.table.item(i, column).text() == "no: layout_refused"
        assert REASONS["layout_refused"] in dock.table.item(i, column).toolTip()
        assert REASONS["layout_refused"] in dock.table.item(i, 0).toolTip()
    header = dock.table.horizontalHeaderItem(column).toolTip()
    assert all(f"{code}: {meaning}" in header for code, meaning in REASONS.items())
    assert "invalid_design" in header and "evaluation_refused" in header


def test_gradient_psf_engineering_lowers_the_objective_and_loads_the_final_design(qtbot, window):
    dock, state = window.optimise, window.state
    _poor_start(window)
    start = state.design
    dock.set_method("gradient-psf")
    _free_focus(dock)
    dock.g_steps.setText("3")
    dock.g_lr.setText("0.1")
    dock.run_button.click()
    _done(qtbot, window)
    steps, final = dock.rows[:-1], dock.rows[-1]
    assert [r.number for r in steps] == [0, 1, 2] and final.number == 3 and dock.best() is final
    values = [r.values["axial_crb"] for r in steps]
    assert values[0] > 0 and final.values["axial_crb"] < values[0]  # the loss went down from its start
    assert steps[0].params == pytest.approx(POOR)  # the descent starts from the design in force
    # The same run straight through the engine: the same values (the runs are deterministic).
    reference = _quiet(
        lambda: optimize_psf(
            start,
            SPACE,
            "axial_crb",
            steps=3,
            lr=0.1,
            settings=EvaluationSettings(crop=256),
            options={"photons": CRB_PHOTONS, "background": 1.0},  # the CLI's (and the dock's) defaults
        )
    )
    assert values == pytest.approx([h.value for h in reference.history], rel=1e-6)
    assert final.values["axial_crb"] == pytest.approx(reference.final_value, rel=1e-6)
    assert "float32 vs float64 start gradient" in dock.message.text() and "within" in dock.message.text()
    # the loss curve: one point per step and the final design, joined
    xs, ys = dock.feasible_dots.getData()
    assert list(xs) == [0, 1, 2, 3] and list(ys) == pytest.approx([*values, final.values["axial_crb"]])
    assert dock.plot.getPlotItem().getAxis("bottom").labelText == "step"
    # the axis reads the values as they are (CRBs of a few nm in µm: no "(x0.001)" scale on the axis)
    left = dock.plot.getPlotItem().getAxis("left")
    assert max(ys) < 1 and left.autoSIPrefixScale == 1.0 and "(x0." not in left.labelString()
    assert "µm" in left.labelString() and " um" not in dock.message.text() and "µm" in dock.message.text()
    # the run table's columns are labelled as the free-parameter table labels them (the path on hover)
    headers = [dock.table.horizontalHeaderItem(c) for c in range(dock.table.columnCount())]
    shown = {h.toolTip(): h.text() for h in headers[1:3]}
    assert shown == {FOCAL: "All lenslets: focal length (mm)", DISTANCE: _label(dock, DISTANCE)}
    assert "_mm" not in shown[DISTANCE]
    dock.table.cellDoubleClicked.emit(len(dock.rows) - 1, 0)
    for path, value in SPACE.values_of(state.design).items():
        assert value == pytest.approx(final.params[path]) and BOUNDS[path][0] <= value <= BOUNDS[path][1]
    assert SPACE.values_of(state.design) == pytest.approx(SPACE.values_of(reference.design))
    assert "final design" in dock.message.text()


def test_gradient_end_to_end_reports_the_held_out_loss(qtbot, window):
    dock = window.optimise
    _poor_start(window)
    dock.set_method("gradient-end-to-end")
    _free_focus(dock)
    for field, text in ((dock.g_steps, "2"), (dock.g_lr, "0.1"), (dock.e_batch, "1"), (dock.e_held_out, "1"),
                        (dock.e_iterations, "2")):  # fmt: skip
        field.setText(text)
    dock.g_check.setChecked(False)
    dock.run_button.click()
    _done(qtbot, window)
    assert [r.number for r in dock.rows] == [0, 1, 2] and dock.best() is dock.rows[-1]
    steps, final = dock.rows[:-1], dock.rows[-1]
    assert all(0 < r.values["task_loss"] < 1.5 for r in steps)  # energy-normalised MSE (all-zero: 1)
    text = dock.message.text()
    assert "held-out" in text and "all-zero volume 1" in text and "float64" not in text
    assert final.note == "final design (last point)"
    # Each step's training loss is measured before its update: none was measured at the final design, so
    # its cell says so, the plot has no point there, and the message gives the last step's loss as that step's.
    assert final.feasible and "task_loss" not in final.values
    table = {dock.table.horizontalHeaderItem(c).text(): c for c in range(dock.table.columnCount())}
    assert dock.table.item(2, table["task_loss"]).text() == "not evaluated"
    assert dock.table.item(1, table["task_loss"]).text() == f"{steps[1].values['task_loss']:.6g}"
    xs, ys = dock.feasible_dots.getData()
    assert list(xs) == [0, 1] and list(ys) == pytest.approx([r.values["task_loss"] for r in steps])
    assert list(dock.best_curve.getData()[0]) == [
        0,
        1,
    ]  # the best-so-far line stops at the last measured step
    last = f"{steps[1].values['task_loss']:.4g}"
    assert f"{last} at step 1 (before its update; not evaluated at the final design)" in text
    assert f"→ {last}" not in text  # not presented as the final design's loss
    held_out = re.search(r"→ ([0-9.]+) at the final design", text)
    assert held_out and 0 < float(held_out.group(1)) < 1.5 and held_out.group(1) in final.message
    assert dock.rows[1].params != pytest.approx(POOR)  # the optics moved
    dock.table.cellDoubleClicked.emit(2, 0)
    assert SPACE.values_of(window.state.design) == pytest.approx(dock.rows[-1].params)


def test_bad_option_values_are_refused_by_name(qtbot, window):
    dock = window.optimise
    dock.set_method("algorithm2")
    dock.a2_min_lenslet.setText("0")
    dock.run_button.click()
    assert "Minimum lenslet size" in dock.message.text() and "out of range" in dock.message.text()
    assert not dock.is_running()
    dock.a2_min_lenslet.setText("5000")  # more than the 3.6 mm pupil
    dock.run_button.click()
    assert "Minimum lenslet size 5000" in dock.message.text() and not dock.is_running()
    dock.a2_min_lenslet.setText("900")
    dock.a2_sizes.setText("2,x")
    dock.run_button.click()
    assert "Sizes must be whole numbers" in dock.message.text() and not dock.is_running()
    dock.a2_sizes.setText("9")
    dock.run_button.click()
    assert "Sizes 9" in dock.message.text() and "cells per side" in dock.message.text()
    dock.set_method("gradient-psf")
    dock.run_button.click()
    assert "no parameter is freed" in dock.message.text()
    _free_focus(dock)
    dock.g_lr.setText("abc")
    dock.run_button.click()
    assert "Learning rate must be a number" in dock.message.text() and not dock.is_running()
    dock.g_lr.setText("0.05")
    dock.free("camera.pixel_pitch_um", 5.0, 7.0, 3)  # not differentiable: the engine says which are
    dock.run_button.click()
    assert "camera.pixel_pitch_um" in dock.message.text() and not dock.is_running()
    dock.set_method("gradient-end-to-end")
    dock.e_batch.setText("0")
    dock.run_button.click()
    assert "Batch 0 is out of range" in dock.message.text() and not dock.is_running()


def test_cancel_keeps_the_previous_results(qtbot, window, monkeypatch):
    dock = window.optimise
    _algorithm2(qtbot, window)
    _done(qtbot, window)
    previous, chosen = list(dock.rows), dock.chosen
    release, calls = threading.Event(), []

    class Gated(ClosedForm):
        def __call__(self, candidate):  # the first layout waits until the test has pressed Cancel
            calls.append(1)
            release.wait(30)
            return super().__call__(candidate)

    factory = (lambda options: Gated("lateral_resolution"), "test: gated closed form")
    monkeypatch.setitem(objectives_module._REGISTRY, "lateral_resolution", factory)
    dock.run_button.click()
    qtbot.waitUntil(lambda: len(calls) == 1, timeout=TIMEOUT_MS)
    dock.cancel_button.click()
    release.set()
    qtbot.waitUntil(lambda: window.state.job(JOB_NAME).state == "cancelled", timeout=TIMEOUT_MS)
    assert dock.rows == previous and dock.chosen == chosen and dock.table.rowCount() == len(previous)
    assert dock.message.text().startswith("Cancelled: the previous results") and len(calls) == 1
    # a failed run keeps them too, and shows the error, not a traceback
    dock.set_method("gradient-psf")
    _free_focus(dock)
    dock.g_steps.setText("2")
    monkeypatch.setattr(
        "lfm_studio.ui.optimise_model.optimize_psf",
        lambda *a, **k: (_ for _ in ()).throw(ValueError("the start design is infeasible (test)")),
    )
    dock.run_button.click()
    qtbot.waitUntil(lambda: window.state.job(JOB_NAME).state == "failed", timeout=TIMEOUT_MS)
    assert dock.rows == previous and "Failed: the start design is infeasible (test)" in dock.message.text()
    assert "Traceback" not in dock.message.text() and "previous results" in dock.message.text()


def test_a_gradient_run_hands_over_each_step_as_it_is_stored():
    base = _quiet(lambda: SPACE.apply(small_fourier_design(), POOR))
    request = GradientRequest(
        "psf", tuple(FreeParameter(p, *b) for p, b in BOUNDS.items()), steps=3, lr=0.1, check_float64=False
    )
    live, progress = [], []
    result = _quiet(
        lambda: run_gradient(base, request, on_row=live.append, progress=lambda *a: progress.append(a))
    )
    assert [r.number for r in live] == [0, 1, 2] == [r.number for r in result.rows[:-1]]
    for shown, final in zip(live, result.rows, strict=False):
        assert shown.params == pytest.approx(final.params) and shown.values == pytest.approx(final.values)
        assert shown.design() == final.design()  # the stored step's design is the step's point
    assert [p[:2] for p in progress] == [(0, 3), (1, 3), (2, 3), (3, 3)]


def test_a_refusal_stays_shown_while_its_field_still_holds_the_refused_number(window, qtbot):
    """Committing another option field does not hide a refusal that still stands."""
    dock = window.optimise
    dock.set_method("gradient-end-to-end")
    dock.e_batch.setText("0")  # below the minimum of 1
    dock.e_batch.commit()
    refusal = dock.e_batch.error()
    assert refusal is not None and refusal in dock.message.text()
    dock.g_steps.setText("5")
    dock.g_steps.commit()
    assert refusal in dock.message.text()  # the batch field still holds "0"
    dock.e_batch.setText("3")
    dock.e_batch.commit()
    assert dock.e_batch.error() is None and dock.message.text() == ""


def test_the_psf_crop_follows_the_design_until_edited(window):
    # The XLFM preset's 27 views: a 256 px crop holds none of their spots, 512 px holds 3 (engine
    # test_crop); the dock's crop fields and its grid search take the design's automatic crop.
    dock = window.optimise
    window.state.set_design(_quiet(lambda: load_preset("xlfm_cong2017")))
    assert dock.g_crop.value() == dock.a2_crop.value() == auto_crop(window.state.design) == 512
    dock.a2_crop.setText("640")
    assert dock.a2_crop.commit()
    window.state.set_design(_quiet(lambda: load_preset("flfm_guo2019")))
    assert dock.g_crop.value() == auto_crop(window.state.design) == 256  # followed the design
    assert dock.a2_crop.value() == 640  # edited: kept
    _free_focus(dock)
    assert dock.build_request().crop == 256
    # An edited value stays even when it equals an automatic crop (it was compared by value before,
    # so 256 typed on the XLFM, kept on the FLFM whose automatic crop is 256, became 512 on the way back).
    window.state.set_design(_quiet(lambda: load_preset("xlfm_cong2017")))
    assert dock.g_crop.value() == 512
    dock.g_crop.setText("256")
    assert dock.g_crop.commit()
    for name in ("flfm_guo2019", "xlfm_cong2017"):
        window.state.set_design(_quiet(lambda name=name: load_preset(name)))
        assert dock.g_crop.value() == 256 and dock.a2_crop.value() == 640


def test_a_resumed_grid_study_keeps_its_stored_crop(tmp_path):
    # The dock's grid search now asks for the design's automatic crop (512 px on the XLFM); a study it
    # stored with another crop (e.g. the old fixed one) resumes with that crop instead of being refused.
    from lfm_studio.engine.optimize.study import load_study
    from lfm_studio.ui.optimise_model import OptimiseRequest, run_optimisation

    design = _quiet(lambda: load_preset("xlfm_cong2017"))
    free = (FreeParameter("relay.focal_length_mm", 150.0, 170.0, 2),)
    path = str(tmp_path / "grid.db")
    run_optimisation(design, OptimiseRequest(free, ("number_of_views",), budget=1, study=path, crop=128))
    again = OptimiseRequest(free, ("number_of_views",), budget=2, study=path, resume=True, crop=512)
    assert len(run_optimisation(design, again)) == 2
    assert load_study(path).user_attrs["settings"]["crop"] == 128


def test_grid_and_algorithm2_take_axial_crbs_photons_and_background(window):
    """walk4 #3: the dock scored axial_crb at 1000 photons without a field, the CLI at 1e5."""
    dock = window.optimise
    dock.c_photons.setText("2000")
    dock.c_background.setText("5")
    dock.set_method("algorithm2")
    dock.a2_objective.setCurrentText("axial_crb")
    request = dock.build_request()
    assert (request.crb_photons, request.crb_background) == (2000.0, 5.0)
    built = build_objective(request.objective, {}, request.crb_photons, request.crb_background)
    assert score_options(built) == {"photons": 2000.0, "background": 5.0}
    # a task score keeps its own photons per image
    assert score_options(build_objective("task_ncc", {}, 2000.0, 5.0))["photons"] == TASK_PHOTONS


def test_a_resumed_grid_study_refuses_other_crb_photons(tmp_path):
    from lfm_studio.ui.optimise_model import OptimiseRequest, run_optimisation

    design = small_fourier_design()
    free = (FreeParameter(DISTANCE, 16.0, 17.0, 2),)
    path = str(tmp_path / "crb.db")
    run_optimisation(design, OptimiseRequest(free, ("axial_crb",), budget=1, study=path, crb_photons=1e5))
    again = OptimiseRequest(free, ("axial_crb",), budget=2, study=path, resume=True, crb_photons=1000.0)
    with pytest.raises(ValueError, match=r"axial_crb photons: stored 100000.0, now 1000.0"):
        run_optimisation(design, again)
