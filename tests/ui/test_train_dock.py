"""The studio's Train dock in the window ``lfm-studio gui`` builds: a tiny training with a live loss
curve, cancel keeping the previous model, save without silent overwrite, and RL vs the learned model
on the studio's own simulated image, scored beside the all-zero floor."""

from __future__ import annotations

import math
from dataclasses import replace
from types import SimpleNamespace

import pytest
import torch
from qtpy.QtCore import QSettings
from qtpy.QtWidgets import QDockWidget, QMessageBox

from lfm_studio.engine.learned.checkpoint import read_checkpoint
from lfm_studio.ui.app import build_studio
from lfm_studio.ui.training import TrainSettings, jitter_refusal, parse_photons, running_mean
from tests.ui.standins import FakeMLAEditor, FakePSFViewer, small_fourier_design

TIMEOUT_MS = 600_000  # generous: the machine is shared; never a statement about speed


@pytest.fixture
def window(qtbot, tmp_path):
    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    threads = torch.get_num_threads()
    window = build_studio(
        small_fourier_design(), settings=settings, preview=False, debounce_ms=10,
        editor_factory=lambda d: FakeMLAEditor(d.mla.lenslets), viewer_factory=FakePSFViewer,
    )  # fmt: skip
    window.show()
    qtbot.waitExposed(window)
    window.controller.start()
    qtbot.waitUntil(lambda: window.state.psf is not None and not window.state.psf.preview, timeout=TIMEOUT_MS)
    yield window
    window.file_actions.confirm_discard = lambda: True  # never block on a dialog in teardown
    window.controller.shutdown()
    window.close()
    torch.set_num_threads(threads)


def _points(dock):
    steps, _ = dock.loss_curve.getData()
    checked, _ = dock.validation_points.getData()
    return (0 if steps is None else len(steps)), (0 if checked is None else len(checked))


def test_settings_refuse_bad_input_naming_the_field():
    assert parse_photons("1e4, 1e5  2e6") == (1e4, 1e5, 2e6)
    with pytest.raises(ValueError, match="photon budgets must be numbers"):
        parse_photons("1e4, many")
    with pytest.raises(ValueError, match="photon budgets must be positive"):
        parse_photons("0, 1e5")
    with pytest.raises(ValueError, match="model must be one of"):
        TrainSettings(model="resnet")
    with pytest.raises(ValueError, match="minutes must be a positive"):
        TrainSettings(minutes=0.0)
    with pytest.raises(ValueError, match=r"optics jitter must be a relative jitter between 0 and 0\.2"):
        TrainSettings(optics_jitter=3.0)  # a percentage where a fraction belongs
    assert jitter_refusal(TrainSettings(), None) is None  # off: no design needed
    assert "needs the design" in jitter_refusal(TrainSettings(optics_jitter=0.03), {"name": "a bare stack"})
    assert running_mean([1.0, 3.0, 5.0, 7.0], 2) == pytest.approx([1.0, 2.0, 4.0, 6.0])


def test_train_live_curve_cancel_save_and_compare_with_rl(qtbot, window, tmp_path, monkeypatch):
    dock = window.train_dock
    assert "Train" in {d.windowTitle() for d in window.findChildren(QDockWidget)}
    assert not dock.save_button.isEnabled() and not dock.compare_button.isEnabled()

    # A tiny training: 4 steps, validation every 10 steps and at the last one.
    dock.max_steps.setValue(4)
    dock.photons.setText("1e5, 1e6")
    live: list[tuple[int, float, float]] = []
    on_step = dock._on_step
    monkeypatch.setattr(dock, "_on_step", lambda point: (live.append(point), on_step(point)))
    assert dock.start_training()
    qtbot.waitUntil(lambda: dock.trained is not None, timeout=TIMEOUT_MS)
    first = dock.trained
    # every step reached the GUI while training ran (engine on_step -> ctx.partial), as the history says
    assert [(s, loss) for s, loss, _ in live] == [(s, loss) for s, loss, _ in first.result.history]
    assert [math.isnan(v) for *_, v in live] == [True, True, True, False]
    assert [step for step, _, _ in first.result.history] == [1, 2, 3, 4]
    assert _points(dock) == (4, 1)  # a loss point per step, the final validation point
    item = dock.plot.getPlotItem()  # the key sits above the data: no legend box over the curves
    assert item.legend is None and "●</span> validation" in item.titleLabel.text
    assert all(math.isfinite(loss) and loss > 0 for _, loss, _ in first.result.history)
    assert first.result.header.training["best_validation"] < first.result.header.training["zero_floor"]
    assert "4 steps" in dock.message.text() and "unrolled-rl" in dock.message.text()

    # Cancel: a long run is stopped after its first steps; the previous model and its curve stay.
    dock.max_steps.setValue(100_000)
    monkeypatch.setattr(
        dock, "_confirm_replace_unsaved", lambda what: True
    )  # train again over the unsaved one
    assert dock.start_training()
    qtbot.waitUntil(lambda: len(dock.live) >= 1, timeout=TIMEOUT_MS)
    dock.cancel()
    qtbot.waitUntil(lambda: not dock.runner.is_running("train"), timeout=TIMEOUT_MS)
    assert dock.trained is first and _points(dock) == (4, 1)
    assert "cancelled" in dock.message.text()
    assert len(_stopped_steps(dock)) >= 1  # how far the cancelled run got, dashed beside the kept curve

    # Save: atomic, and an existing file is replaced only after a yes.
    target = tmp_path / "model.safetensors"
    monkeypatch.setattr(dock, "_ask_path", lambda: str(tmp_path / "model"))
    assert dock.save() == target and target.stat().st_size > 0
    before = target.read_bytes()
    target.write_bytes(b"keep me")
    monkeypatch.setattr(dock, "_confirm_overwrite", lambda path: False)
    assert dock.save() is None and target.read_bytes() == b"keep me"
    monkeypatch.setattr(dock, "_confirm_overwrite", lambda path: True)
    assert dock.save() == target and target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".") or "tmp" in p.name] == []

    # Compare: no image yet is a message; then RL and the model on the studio's own image.
    assert window.state.image is None and not dock.compare()
    assert "Simulate image" in dock.message.text()
    window.state.set_workflow(replace(window.state.workflow, bead_count=5))  # fits the tiny volume
    window.controller.request_image()
    qtbot.waitUntil(lambda: window.state.image is not None, timeout=TIMEOUT_MS)
    assert dock.compare()
    qtbot.waitUntil(lambda: dock.comparison is not None, timeout=TIMEOUT_MS)
    comparison = dock.comparison
    assert comparison.rl.method == "rl-accelerated" and comparison.learned.method == "learned"
    truth = window.state.image.ground_truth
    assert comparison.rl.volume.shape == comparison.learned.volume.shape == truth.shape
    assert not torch.equal(comparison.rl.volume, comparison.learned.volume)
    rows = {dock.table.item(r, 0).text(): [dock.table.item(r, c).text() for c in (1, 2, 3)]
            for r in range(dock.table.rowCount())}  # fmt: skip
    assert set(rows) == {"NCC", "bead F1", "PSNR (dB)", "SSIM"}
    for label in ("PSNR (dB)", "SSIM"):  # both sides scored, beside the all-zero volume's score
        rl, learned, zero = (float(v) for v in rows[label])
        assert math.isfinite(rl) and math.isfinite(learned) and math.isfinite(zero)
    rl_ncc = comparison.rl.scores.score("ncc").value
    assert float(rows["NCC"][0]) == pytest.approx(rl_ncc, abs=5e-4) and rl_ncc > 0.3
    assert comparison.learned.scores.score("ncc").value > 0.0  # a real volume, not the trivial answer
    shown = [(name, shape) for call, name, shape in window.viewer.calls if call == "show_volume"]
    assert ("RL", tuple(truth.shape)) in shown and ("learned", tuple(truth.shape)) in shown

    # The comparison's layers: fresh after Compare, and after Compare again with nothing changed;
    # stale once a setting they were made with changed (they were never marked).
    assert not {"RL", "learned"} & set(window.viewer.stale_marks)
    assert dock.compare()
    qtbot.waitUntil(lambda: dock.comparison is not comparison, timeout=TIMEOUT_MS)
    assert not {"RL", "learned"} & set(window.viewer.stale_marks)
    window.state.set_workflow(replace(window.state.workflow, iterations=window.state.workflow.iterations + 1))
    head = "stale: made with the previous design or settings"
    assert {layer: window.viewer.stale_marks.get(layer) for layer in ("RL", "learned")} == {
        "RL": head,
        "learned": head,
    }


def test_an_unsaved_trained_model_is_unsaved_input_until_saved(monkeypatch, qtbot, window, tmp_path):
    # (monkeypatch first: its dialog stand-ins outlive the window's closing in teardown)
    dock, state = window.train_dock, window.state
    questions: list[str] = []
    answers: list[QMessageBox.StandardButton] = []

    def question(parent, title, text, *args, **kwargs):
        questions.append(text)
        return answers.pop(0)

    monkeypatch.setattr(QMessageBox, "question", question)
    dock.max_steps.setValue(2)
    dock.photons.setText("1e5")
    assert dock.start_training()
    qtbot.waitUntil(lambda: dock.trained is not None, timeout=TIMEOUT_MS)
    assert "Not saved yet" in dock.message.text() and "Save checkpoint…" in dock.message.text()
    assert state.unsaved_model == "the trained unrolled-rl model (2 steps)"
    assert state.unsaved_input and not state.dirty and window.isWindowModified()

    # Closing the studio asks; Cancel keeps the window open and the model.
    answers.append(QMessageBox.StandardButton.Cancel)
    assert not window.close()
    assert window.isVisible() and dock.trained is not None
    assert questions[-1].startswith("The trained unrolled-rl model (2 steps) is not saved and will be lost.")
    assert "Save checkpoint… in the Train dock" in questions[-1]

    # Training again asks too; Cancel starts nothing.
    first = dock.trained
    answers.append(QMessageBox.StandardButton.Cancel)
    assert not dock.start_training()
    assert "training again replaces it" in questions[-1]
    assert not dock.runner.is_running("train") and dock.trained is first

    # Saved: nothing unsaved, closing (here: the check closeEvent makes) asks nothing.
    monkeypatch.setattr(dock, "_ask_path", lambda: str(tmp_path / "kept"))
    assert dock.save() == tmp_path / "kept.safetensors"
    assert state.unsaved_model is None and not state.unsaved_input and not window.isWindowModified()
    asked = len(questions)
    assert window.file_actions.confirm_discard() and len(questions) == asked


def _three_steps_then(stop: str):
    """Stands in for train_model: streams three loss points, then fails (stop="fail") or runs until cancelled."""

    def run(ctx, design, stack, settings):
        for step in (1, 2, 3):
            ctx.partial((step, 1.0 / step, math.nan))
        if stop == "fail":
            raise RuntimeError("out of memory")
        while True:
            ctx.check()
            ctx.cancel.wait(0.01)

    return run


def _stopped_steps(dock):
    steps, _ = dock.stopped_curve.getData()
    return [] if steps is None else [int(s) for s in steps]


@pytest.mark.parametrize("stop", ["cancel", "fail"])
def test_a_stopped_first_run_leaves_its_curve_dashed_beside_the_kept_model(qtbot, window, monkeypatch, stop):
    """Walk 4: Cancel wiped the loss curve of a first run, so one could not see how far it got."""
    dock = window.train_dock
    monkeypatch.setattr("lfm_studio.ui.train_dock.train_model", _three_steps_then(stop))
    assert dock.start_training()
    qtbot.waitUntil(lambda: len(dock.live) == 3 or not dock.runner.is_running("train"), timeout=TIMEOUT_MS)
    dock.cancel()
    qtbot.waitUntil(lambda: not dock.runner.is_running("train"), timeout=TIMEOUT_MS)
    assert dock.trained is None and _points(dock) == (0, 0)  # no model kept: no kept curve
    assert _stopped_steps(dock) == [1, 2, 3]  # the stopped run, dashed
    assert "stopped run (not kept)" in dock.plot.getPlotItem().titleLabel.text
    said = "training failed after 3 step(s)" if stop == "fail" else "training cancelled after 3 step(s)"
    assert said in dock.message.text()
    # The next run starts from clean axes.
    monkeypatch.setattr("lfm_studio.ui.train_dock.train_model", _three_steps_then("cancel"))
    assert dock.start_training()
    assert _stopped_steps(dock) == [] and "stopped run" not in dock.plot.getPlotItem().titleLabel.text
    qtbot.waitUntil(lambda: len(dock.live) == 3, timeout=TIMEOUT_MS)
    dock.cancel()
    qtbot.waitUntil(lambda: not dock.runner.is_running("train"), timeout=TIMEOUT_MS)
    assert _stopped_steps(dock) == [1, 2, 3]
    # Another document drops the stopped run's line (it was for the previous design).
    window.state.replace_design(window.state.design)
    assert _stopped_steps(dock) == [] and "stopped run" not in dock.plot.getPlotItem().titleLabel.text


def test_optics_jitter_field_trains_with_the_augmentation_and_records_it(
    qtbot, window, tmp_path, monkeypatch
):
    dock = window.train_dock
    assert dock.jitter.text() == "off" and dock.settings().optics_jitter == 0.0
    assert "one PSF simulation per jittered design" in dock.jitter.toolTip()
    dock.max_steps.setValue(2)
    dock.photons.setText("1e5, 1e6")

    # A value beyond 20 % is refused, naming the field and the fix; Train does not start with the old value.
    dock.jitter.setText("50 %")
    assert not dock.start_training()
    assert (
        "Optics jitter 50 is out of range" in dock.message.text() and "from 0 to 20 %" in dock.message.text()
    )
    assert not dock.runner.is_running("train") and dock.trained is None

    # 3 %: the training spec and the checkpoint header record a jitter of 0.03.
    dock.jitter.setText("3 %")
    assert dock.start_training()
    assert "optics jitter ±3 %" in dock.message.text()
    qtbot.waitUntil(lambda: dock.trained is not None, timeout=TIMEOUT_MS)
    trained = dock.trained
    assert trained.settings.optics_jitter == pytest.approx(0.03)
    data = trained.result.header.data
    assert data["optics_jitter"] == pytest.approx(0.03) and data["jitter_designs"] >= 1
    assert data["jitter_validation"] is False
    assert [step for step, _, _ in trained.result.history] == [1, 2]
    assert "unrolled-rl (optics jitter ±3 %): " in dock.message.text()
    monkeypatch.setattr(dock, "_ask_path", lambda: str(tmp_path / "jittered"))
    saved = dock.save()
    assert read_checkpoint(saved)[0].data["optics_jitter"] == pytest.approx(0.03)

    # A PSF stack without its design (e.g. a measured one) cannot be jittered: a message, no job.
    psf = window.state.psf
    monkeypatch.setattr(
        dock, "state", SimpleNamespace(psf=replace(psf, design=SimpleNamespace(name="measured")))
    )
    assert not dock.start_training()
    assert (
        "Optics jitter 3 % needs the design" in dock.message.text()
        and "Fix: set Optics jitter to off" in (dock.message.text())
    )
    assert not dock.runner.is_running("train") and dock.trained is trained


def test_comparison_layers_are_stale_only_after_a_change_since_the_comparison(qtbot):
    """The layers of Compare with RL ("RL", "learned") had no stale mark at all: a change of the design
    or settings (or, for "learned", another model) since the comparison marks them; a run asked for
    again with nothing changed does not."""
    from lfm_studio.ui.edits import apply_changes
    from lfm_studio.ui.state import StudioState
    from lfm_studio.ui.train_dock import ComparedWith, TrainDock
    from lfm_studio.widgets.jobs import JobRunner

    design = small_fourier_design()
    state, runner = StudioState(design), JobRunner()
    dock = TrainDock(state, runner)
    qtbot.addWidget(dock)
    dock.trained = SimpleNamespace(name="the model compared")
    for stage in ("psf", "image", "reconstruction"):
        state.mark_fresh(stage)
    dock.compared_with = ComparedWith(state.inputs_version("reconstruction"), False, dock.trained)
    assert dock.layer_marks() == {}
    state.mark_stale("image", "reconstruction", changed=False)  # Simulate pressed again: no change
    assert dock.layer_marks() == {}
    dock.trained = SimpleNamespace(name="trained again")
    assert {k: m.text for k, m in dock.layer_marks().items()} == {
        "learned": "stale: made with the previous trained model"
    }
    state.set_design(apply_changes(design, {"camera.read_noise_e": 2.0}))  # a new image is due
    assert {k: m.text for k, m in dock.layer_marks().items()} == {
        "RL": "stale: made with the previous design or settings",
        "learned": "stale: made with the previous design or settings and trained model",
    }
    state.mark_stale("image", changed=False)
    dock.compared_with = ComparedWith(state.inputs_version("reconstruction"), True, dock.trained)
    assert set(dock.layer_marks()) == {"RL", "learned"}  # compared on an image already out of date
    dock.disconnect_state()
    assert runner.shutdown(5000)
