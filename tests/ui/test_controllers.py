"""Controllers: the recompute chain on the small Fourier design, the MLA editor and viewer bindings.

The editor and viewer are stand-ins with the brief's widget contracts (tests/ui/standins.py).
"""

from __future__ import annotations

import threading
from types import SimpleNamespace

import pytest

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.progress import checkpoint
from lfm_studio.ui import pipeline
from lfm_studio.ui.controllers import MLAEditorBinding, StudioController, ViewerBinding
from lfm_studio.ui.edits import apply_changes
from lfm_studio.ui.state import StudioState
from lfm_studio.widgets.mla_editor import MLAEditor
from tests.ui.standins import FakeMLAEditor, FakePSFViewer, small_conventional_design, small_fourier_design

TIMEOUT_MS = 60_000  # generous: only a hang should reach it (CI may share its cores)


@pytest.fixture(scope="module")
def design():
    return small_fourier_design()


@pytest.fixture
def studio(qtbot, design):
    state = StudioState(design)
    controller = StudioController(state, debounce_ms=10, preview=False)
    editor, viewer = FakeMLAEditor(design.mla.lenslets), FakePSFViewer()
    qtbot.addWidget(editor)
    qtbot.addWidget(viewer)
    bindings = (MLAEditorBinding(state, editor, controller), ViewerBinding(state, viewer, controller))
    yield state, controller, editor, viewer
    for binding in bindings:
        binding.disconnect_state()
    controller.shutdown()


def _wait_psf(qtbot, state, generation_before=None):
    qtbot.waitUntil(lambda: state.psf is not None and "psf" not in state.stale, timeout=TIMEOUT_MS)
    qtbot.waitUntil(lambda: not state.job("psf").active, timeout=TIMEOUT_MS)


def test_the_psf_is_computed_and_shown_then_one_edited_lenslet_is_recomputed_alone(qtbot, studio):
    state, controller, editor, viewer = studio
    controller.start()
    _wait_psf(qtbot, state)
    first = state.psf
    assert first.method == "per_lenslet" and first.lenslets_computed == (0, 1, 2, 3)
    assert viewer.calls[-1] == ("show_psf", "PSF", (3, 256, 256))
    misses = controller.cache.misses
    # view -> state: the editor commits lenslet 2 with another focal length.
    lenslets = list(editor.lenslets())
    lenslets[2] = lenslets[2].model_copy(update={"focal_length_mm": 17.5})
    editor.commit(lenslets)
    assert state.design.mla.lenslets[2].focal_length_mm == 17.5 and state.dirty
    qtbot.waitUntil(lambda: state.psf is not first and "psf" not in state.stale, timeout=TIMEOUT_MS)
    assert state.psf.lenslets_computed == (2,)
    assert state.psf.lenslets_cached == (0, 1, 3)
    assert controller.cache.misses == misses + 1
    # The new lenslet changes the stack (not a stale copy).
    assert not bool((state.psf.stack.data == first.stack.data).all())


def test_state_changes_reach_the_editor(qtbot, studio, design):
    state, _, editor, _ = studio
    moved = apply_changes(design, {"mla.lenslets.0.center_um": (-550.0, -600.0)})
    state.set_design(moved)
    assert editor.lenslets() == moved.mla.lenslets
    pupil_um = moved.pupil_diameter_at_mla / 2 * 1e6
    assert editor.pupil_radius_um == pytest.approx(pupil_um)
    assert editor.sensor[0] == pytest.approx((256 * 6.5, 256 * 6.5))


def test_a_design_without_a_pupil_clears_the_editor_s_pupil_footprint(qtbot, studio, design):
    """Fourier -> conventional (File > Open, a preset): no stale pupil circle, no "inside the pupil" check."""
    state, _, editor, _ = studio
    assert editor.pupil_radius_um == pytest.approx(design.pupil_diameter_at_mla / 2 * 1e6)
    state.set_design(small_conventional_design())
    assert editor.pupil_radius_um is None


def test_the_real_editor_drops_the_pupil_circle_and_check_for_a_conventional_design(qtbot, design):
    state = StudioState(design)
    editor = MLAEditor()
    qtbot.addWidget(editor)
    binding = MLAEditorBinding(state, editor)
    assert "all inside the pupil" in editor.status_text()
    state.set_design(small_conventional_design())
    assert "pupil" not in editor.canvas.getPlotItem().titleLabel.text
    assert "pupil" not in editor.status_text()
    binding.disconnect_state()


def test_the_editor_describes_a_regular_grid_instead_of_checking_its_patch(qtbot, design):
    """A 106 x 106 conventional grid: the editor draws a central patch, so its status gives the grid's
    size, pitch and lenslet focal length and where to change them, and claims no check of the patch."""
    state = StudioState(design)
    editor = MLAEditor()
    qtbot.addWidget(editor)
    binding = MLAEditorBinding(state, editor)
    state.set_design(load_preset("lfm_10x_na03"))
    status = editor.status_text()
    for part in ("106 rows x 106 lenslets (11236 in all)", "pitch 125 µm", "focal length 1.875 mm",
                 "design file", "Optimise dock"):  # fmt: skip
        assert part in status, part
    assert "OK" not in status and "100 lenslets" not in status
    assert "overlap" not in editor.sensor_view.getPlotItem().titleLabel.text
    assert editor.toolTip() == status
    state.set_design(design)  # an explicit layout: its checks again
    assert "OK:" in editor.status_text() and editor.toolTip() == ""
    binding.disconnect_state()


def test_an_overlapping_lenslet_from_the_editor_is_refused_and_the_design_kept(qtbot, studio, design):
    state, _, editor, _ = studio
    lenslets = list(editor.lenslets())
    lenslets[1] = lenslets[1].model_copy(update={"center_um": (-300.0, -600.0)})  # 300 um from lenslet 0
    editor.commit(lenslets)
    assert state.design == design
    assert "overlap" in state.errors["mla"]
    editor.commit(design.mla.lenslets)  # back to a valid layout: the error goes
    assert "mla" not in state.errors


def test_quick_edits_are_debounced_into_one_psf_job(qtbot, studio, design):
    state, controller, _, _ = studio
    controller.start()
    _wait_psf(qtbot, state)
    before = controller.runner.generation("psf")
    for na in (0.90, 0.85, 0.80):
        state.set_design(apply_changes(design, {"objective.numerical_aperture": na}))
    _wait_psf(qtbot, state)
    qtbot.waitUntil(lambda: state.psf.design.objective.numerical_aperture == 0.80, timeout=TIMEOUT_MS)
    assert controller.runner.generation("psf") == before + 1


def test_a_camera_noise_edit_does_not_recompute_the_psf(qtbot, studio, design):
    state, controller, _, _ = studio
    controller.start()
    _wait_psf(qtbot, state)
    before = controller.runner.generation("psf")
    state.set_design(apply_changes(design, {"camera.read_noise_e": 2.5}))
    controller.flush()
    assert controller.runner.generation("psf") == before
    assert "psf" not in state.stale


def _slow_psf(ctx, request, cache):
    """Stands in for the PSF stage: an engine-like loop that only ends when cancelled."""
    while True:
        checkpoint(ctx.cancel, ctx.progress, 0, 10, "lenslet 1/10")
        ctx.cancel.wait(0.01)


def test_cancel_keeps_the_previous_psf(qtbot, studio, design, monkeypatch):
    state, controller, _, viewer = studio
    controller.start()
    _wait_psf(qtbot, state)
    previous, shown = state.psf, list(viewer.calls)
    monkeypatch.setattr(pipeline, "compute_psf", _slow_psf)
    state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))
    controller.flush()
    qtbot.waitUntil(lambda: state.job("psf").total == 10, timeout=TIMEOUT_MS)
    controller.cancel()
    qtbot.waitUntil(lambda: state.job("psf").state == "cancelled", timeout=TIMEOUT_MS)
    assert state.psf is previous
    assert viewer.calls == shown
    assert "psf" in state.stale  # still out of date: the next edit recomputes it


def test_a_late_result_from_superseded_parameters_is_dropped(qtbot, studio, design, monkeypatch):
    state, controller, _, _ = studio
    real = pipeline.compute_psf
    entered, gate = threading.Event(), threading.Event()

    def gated(ctx, request, cache):
        if request.design.wavelength_nm != 700.0:
            return real(ctx, request, cache)
        entered.set()
        # A job that misses its cancel checkpoints (e.g. one long FFT) and finishes after the new one.
        deaf = SimpleNamespace(
            cancel=threading.Event(), progress=ctx.progress, partial=ctx.partial, check=lambda *_: None
        )
        result = real(deaf, request, cache)
        gate.wait(60)
        return result

    monkeypatch.setattr(pipeline, "compute_psf", gated)
    state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))
    controller.flush()
    assert entered.wait(60)
    newest = apply_changes(design, {"wavelength_nm": 690.0})
    state.set_design(newest)
    controller.flush()
    qtbot.waitUntil(lambda: state.psf is not None and state.psf.design == newest, timeout=TIMEOUT_MS)
    gate.set()
    qtbot.waitUntil(lambda: controller.runner.dropped == 1, timeout=TIMEOUT_MS)
    assert state.psf.design == newest and "psf" not in state.stale


def test_preview_then_full_stack(qtbot, design):
    from lfm_studio.engine.design import DepthSpec

    deeper = design.updated(depths=DepthSpec(depth_range_um=(-10.0, 10.0), depth_step_um=2.0))  # 11 depths
    state = StudioState(deeper)
    controller = StudioController(state, debounce_ms=10, preview=True)
    previews = []
    state.preview_changed.connect(previews.append)
    controller.start()
    qtbot.waitUntil(lambda: state.psf is not None, timeout=TIMEOUT_MS)
    controller.shutdown()
    assert len(previews) == 1 and previews[0].preview
    assert len(previews[0].stack.depths) == pipeline.PREVIEW_DEPTHS
    assert len(state.psf.stack.depths) == 11 and not state.psf.preview


def test_a_preview_the_engine_refuses_is_skipped_and_the_full_stack_still_comes(qtbot, design, monkeypatch):
    # e.g. the default XLFM with 13 um pixels: its 2x-binned preview cannot hold the 1 mm lenslets.
    from lfm_studio.engine.design import DepthSpec

    deeper = design.updated(depths=DepthSpec(depth_range_um=(-10.0, 10.0), depth_step_um=2.0))  # 11 depths
    real = pipeline._psf_result

    def refuse_previews(design, run, depths, device, cache, ctx, preview):
        if preview:
            raise ValueError(
                "oversampling 1 is too small for lenslet at (0, 0) m. Fix: use oversampling >= 2."
            )
        return real(design, run, depths, device, cache, ctx, preview)

    monkeypatch.setattr(pipeline, "_psf_result", refuse_previews)
    state = StudioState(deeper)
    controller = StudioController(state, debounce_ms=10, preview=True)
    messages, previews = [], []
    state.job_changed.connect(lambda status: messages.append(status.message))
    state.preview_changed.connect(previews.append)
    controller.start()
    qtbot.waitUntil(lambda: state.job("psf").state in ("done", "failed"), timeout=TIMEOUT_MS)
    controller.shutdown()
    assert state.job("psf").state == "done" and len(state.psf.stack.depths) == 11
    assert previews == [] and any(m.startswith("PSF preview skipped (oversampling 1") for m in messages)


def test_image_then_reconstruction_with_quality(qtbot, studio):
    state, controller, _, viewer = studio
    from lfm_studio.ui.results import WorkflowSettings

    state.set_workflow(WorkflowSettings(bead_count=3, photons=1e6, seed=1, iterations=2))
    controller.start()
    _wait_psf(qtbot, state)
    controller.request_image()
    qtbot.waitUntil(lambda: state.image is not None, timeout=TIMEOUT_MS)
    assert state.camera_image.shape == (256, 256) and int((state.ground_truth > 0).sum()) == 3
    assert ("show_image", "light field", (256, 256)) in viewer.calls
    if not pipeline.reconstruction_available():
        pytest.skip("lfm_studio.engine.reconstruct is not installed")
    controller.request_reconstruction()
    qtbot.waitUntil(lambda: state.reconstruction is not None, timeout=TIMEOUT_MS)
    result = state.reconstruction
    assert result.iterations == 2 and len(result.ncc_curve) == 2 and len(state.convergence[0]) == 2
    assert result.psnr is not None and result.psnr > 0 and 0 < result.ssim <= 1
    assert viewer.calls[-1][:2] == ("show_volume", "reconstruction")
    # A seed change: image and reconstruction recompute (auto update), the PSF does not.
    psf_generation = controller.runner.generation("psf")
    old_image = state.image
    state.set_workflow(WorkflowSettings(bead_count=3, photons=1e6, seed=2, iterations=2))
    qtbot.waitUntil(
        lambda: state.image is not old_image and "reconstruction" not in state.stale, timeout=TIMEOUT_MS
    )
    assert controller.runner.generation("psf") == psf_generation


def test_without_auto_update_only_the_button_recomputes_the_image(qtbot, studio):
    state, controller, _, _ = studio
    from lfm_studio.ui.results import WorkflowSettings

    state.set_workflow(WorkflowSettings(bead_count=2, seed=1, auto_update=False))
    controller.start()
    _wait_psf(qtbot, state)
    controller.request_image()
    qtbot.waitUntil(lambda: state.image is not None and "image" not in state.stale, timeout=TIMEOUT_MS)
    first = state.image
    state.set_workflow(WorkflowSettings(bead_count=2, seed=2, auto_update=False))
    controller.flush()
    assert state.image is first and "image" in state.stale and not controller.runner.is_running("image")
    controller.request_image()
    qtbot.waitUntil(lambda: state.image is not first, timeout=TIMEOUT_MS)
    assert state.image.info["seed"] == 2


KEPT_CURVES = ((0.2, 0.4, 0.5), (0.5, 0.2, 0.1))  # NCC and relative change of the kept run
PARTIAL_CURVES = ((0.05,), (0.9,))  # what the run that does not finish streams first


@pytest.fixture
def kept_run(qtbot, design):
    """A state holding a finished 3-iteration reconstruction of a fresh image (neither computed here)."""
    import torch

    from lfm_studio.ui.results import ReconstructionResult

    state = StudioState(design)
    controller = StudioController(state, debounce_ms=10, preview=False)
    kept = ReconstructionResult(
        torch.ones(1, 2, 2), (1e-6,) * 3, 3, change_curve=KEPT_CURVES[1], ncc_curve=KEPT_CURVES[0]
    )
    state.set_image(SimpleNamespace(name="image stand-in"))
    state.set_reconstruction(kept)
    for stage in ("psf", "image", "reconstruction"):
        state.mark_fresh(stage)
    yield state, controller, kept
    controller.shutdown()


def _rerun_streaming(qtbot, state, controller, monkeypatch, end):
    """Start a reconstruction that streams PARTIAL_CURVES, then ends with ``end(ctx)`` once the test
    has seen the partial curve on the state (and, for a cancel, cancelled it)."""
    seen = threading.Event()

    def streaming(ctx, design, image, settings):
        ctx.partial(PARTIAL_CURVES)
        assert seen.wait(60)
        return end(ctx)

    monkeypatch.setattr(pipeline, "reconstruct", streaming)
    controller.request_reconstruction()
    qtbot.waitUntil(lambda: state.convergence == PARTIAL_CURVES, timeout=TIMEOUT_MS)  # live while running
    return seen


def _cancel_a_streaming_rerun(qtbot, state, controller, monkeypatch) -> None:
    """Run again, streaming the partial curve until cancelled; press Cancel and wait for it."""

    def until_cancelled(ctx):
        assert ctx.cancel.wait(60)
        ctx.check()

    seen = _rerun_streaming(qtbot, state, controller, monkeypatch, until_cancelled)
    controller.cancel()
    seen.set()
    qtbot.waitUntil(lambda: state.job("reconstruction").state == "cancelled", timeout=TIMEOUT_MS)


def test_a_cancelled_reconstruction_leaves_the_kept_runs_convergence_curve(qtbot, kept_run, monkeypatch):
    state, controller, kept = kept_run

    _cancel_a_streaming_rerun(qtbot, state, controller, monkeypatch)
    assert state.reconstruction is kept and state.convergence == KEPT_CURVES


def test_a_reconstruction_cancelled_before_its_first_iteration_leaves_the_kept_curve(
    qtbot, kept_run, monkeypatch
):
    # The conventional preset's run spends seconds "starting": the plot was emptied and stayed empty.
    state, controller, kept = kept_run
    started = threading.Event()

    def slow_start(ctx, design, image, settings):
        started.set()
        assert ctx.cancel.wait(60)
        ctx.check()

    monkeypatch.setattr(pipeline, "reconstruct", slow_start)
    controller.request_reconstruction()
    assert started.wait(60)
    assert state.convergence == ((), ())  # a new run starts with an empty plot
    controller.cancel()
    qtbot.waitUntil(lambda: state.job("reconstruction").state == "cancelled", timeout=TIMEOUT_MS)
    assert state.reconstruction is kept and state.convergence == KEPT_CURVES


def test_a_failed_reconstruction_leaves_the_kept_runs_convergence_curve(qtbot, kept_run, monkeypatch):
    state, controller, kept = kept_run

    def fail(ctx):
        raise ValueError("reconstruction diverged. Fix: fewer iterations.")

    seen = _rerun_streaming(qtbot, state, controller, monkeypatch, fail)
    seen.set()
    qtbot.waitUntil(lambda: state.job("reconstruction").state == "failed", timeout=TIMEOUT_MS)
    assert state.reconstruction is kept and state.convergence == KEPT_CURVES


def test_a_cancelled_first_reconstruction_leaves_no_curve(qtbot, kept_run, monkeypatch):
    state, controller, _ = kept_run
    state.set_reconstruction(None)
    state.set_convergence((), ())

    _cancel_a_streaming_rerun(qtbot, state, controller, monkeypatch)
    assert state.convergence == ((), ())


def _reconstructed_once(qtbot, studio):
    """The studio's state and controller with a workflow panel and stale marks, after one
    reconstruction of 3 beads (2 iterations); skips where the reconstruction engine is missing."""
    from lfm_studio.ui.results import WorkflowSettings
    from lfm_studio.ui.stale_marks import StaleMarks
    from lfm_studio.ui.workflow_panel import WorkflowPanel

    if not pipeline.reconstruction_available():
        pytest.skip("lfm_studio.engine.reconstruct is not installed")
    state, controller, _, _ = studio
    panel = WorkflowPanel(state)
    qtbot.addWidget(panel)
    marks = StaleMarks(state)
    state.set_workflow(WorkflowSettings(bead_count=3, photons=1e6, seed=1, iterations=2))
    controller.start()
    _wait_psf(qtbot, state)
    controller.request_reconstruction()  # simulates the image first
    qtbot.waitUntil(lambda: state.reconstruction is not None and "reconstruction" not in state.stale,
                    timeout=TIMEOUT_MS)  # fmt: skip
    return state, controller, panel, marks


def test_a_learned_model_path_that_is_not_a_file_fails_in_the_studios_words_and_marks_the_scores_stale(
    qtbot, studio, tmp_path
):
    from dataclasses import replace

    state, _, panel, marks = _reconstructed_once(qtbot, studio)
    kept = state.reconstruction
    assert "NCC" in panel.quality.text() and "stale" not in panel.quality.text()
    assert panel.message.isHidden()

    missing = tmp_path / "nonexistent.safetensors"
    state.set_workflow(replace(state.workflow, method="learned", method_options=(("model", str(missing)),)))
    panel.reconstruct_button.click()
    qtbot.waitUntil(lambda: state.job("reconstruction").state == "failed", timeout=TIMEOUT_MS)
    assert state.reconstruction is kept  # the previous result stays, marked stale
    message = panel.message.text()
    assert not panel.message.isHidden() and message.startswith(
        "Reconstruction failed: Model field: no checkpoint"
    )
    assert str(missing) in message and "Train dock" in message and "Save checkpoint…" in message
    assert "--model" not in message  # not the CLI's wording
    quality = panel.quality.text()
    assert "stale: made with the previous design or settings; the reconstruction failed" in quality
    assert "NCC" in quality  # the kept scores, under the mark
    assert "reconstruction" in marks.marks() and marks.marks()["reconstruction"].activity == "failed"
    marks.disconnect_state()
    panel.disconnect_state()


def test_the_default_bead_count_places_as_many_as_fit_with_a_note_like_the_cli(qtbot, studio):
    from lfm_studio.ui.results import WorkflowSettings
    from lfm_studio.ui.workflow_panel import WorkflowPanel

    state, controller, _, _ = studio
    panel = WorkflowPanel(state)
    qtbot.addWidget(panel)
    panel.simulate_requested.connect(controller.request_image)  # what the window wires
    assert WorkflowSettings().bead_count == 0 and panel.bead_count.text() == "as many as fit"
    controller.start()
    _wait_psf(qtbot, state)
    panel.simulate_button.click()  # the panel's defaults on the small design (20 beads did not fit)
    qtbot.waitUntil(
        lambda: state.image is not None or state.job("image").state == "failed", timeout=TIMEOUT_MS
    )
    assert state.job("image").state != "failed", state.job("image").message
    placed = int((state.ground_truth > 0).sum())
    assert placed >= 1, "no bead placed"
    assert placed < 20, placed  # fewer than the old default: 20 do not fit this design
    assert state.image.info["objects"] == placed
    note = panel.note.text()
    assert not panel.note.isHidden() and note.startswith(
        f"Image: {placed} beads: as many as fit in this volume"
    )
    assert "--count" not in note and "Beads" in note
    # A typed count that does not fit is still refused with the engine's reason (as `image --count`).
    state.set_workflow(WorkflowSettings(bead_count=20, auto_update=False))
    panel.simulate_button.click()
    qtbot.waitUntil(lambda: state.job("image").state == "failed", timeout=TIMEOUT_MS)
    assert "could place only" in panel.message.text()
    panel.disconnect_state()


def test_pressing_reconstruct_again_with_nothing_changed_marks_nothing_stale(qtbot, studio):
    """The scores and the viewer read "stale: made with the previous design or settings; recomputing…"
    when only the button was pressed again: the press counted as a change (and the panel's settings,
    with the method's options written out at their defaults, differed from the state's)."""
    state, controller, panel, marks = _reconstructed_once(qtbot, studio)
    panel.reconstruct_requested.connect(controller.request_reconstruction)
    panel.simulate_requested.connect(controller.request_image)
    for button in (panel.reconstruct_button, panel.simulate_button):
        button.click()  # asked for again, nothing changed: a run, no stale mark (read before it ends)
        assert "stale" not in panel.quality.text() and marks.marks() == {}
        assert "reconstruction" in state.stale and not state.outdated
        qtbot.waitUntil(lambda: not state.stale and not state.busy, timeout=TIMEOUT_MS)
    panel.iterations.setValue(3)  # a change: the scores on screen are the previous settings'
    panel.iterations.committed.emit(3)
    assert "stale: made with the previous design or settings" in panel.quality.text()
    assert state.outdated == {"reconstruction"}
    qtbot.waitUntil(lambda: not state.stale and not state.busy, timeout=TIMEOUT_MS)
    marks.disconnect_state()
    panel.disconnect_state()
