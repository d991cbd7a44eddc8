"""The studio scores a reconstruction with NCC and bead F1 first, beside the all-zero floor."""

from __future__ import annotations

import threading
from dataclasses import replace
from types import SimpleNamespace

import pytest
import torch

from lfm_studio.engine.image_quality import ncc, scorecard
from lfm_studio.engine.io import read_volume, write_volume
from lfm_studio.ui import pipeline
from lfm_studio.ui.file_menu import _scores_metadata
from lfm_studio.ui.plots import ConvergencePlot
from lfm_studio.ui.results import ReconstructionResult, WorkflowSettings
from lfm_studio.ui.state import StudioState
from lfm_studio.ui.workflow_panel import NO_QUALITY, WorkflowPanel, quality_text
from tests.ui.standins import small_fourier_design


def _ctx(partials: list):
    return SimpleNamespace(
        cancel=threading.Event(), progress=lambda *a: None, partial=partials.append, check=lambda *a: None
    )


@pytest.fixture(scope="module")
def psf():
    if not pipeline.reconstruction_available():
        pytest.skip("lfm_studio.engine.reconstruct is not installed")
    design = small_fourier_design()
    return design, pipeline.compute_psf(_ctx([]), pipeline.PSFRequest.for_design(design, preview=False), None)


def _run(psf, photons: float | None):
    design, result = psf
    settings = WorkflowSettings(bead_count=3, photons=photons, seed=1, iterations=6)
    image = pipeline.simulate_image(_ctx([]), design, result.stack, settings)
    partials: list = []
    return image, pipeline.reconstruct(_ctx(partials), design, image, settings), partials


@pytest.fixture(scope="module")
def reconstructed(psf):
    """The studio's reconstruction stage on a noise-free image of 3 beads (6 iterations)."""
    return _run(psf, None)


# This image once reconstructed to an all-zero volume (NCC 0.31, 0.61, 0.50, 0.00, ...): clipping the
# dark pixels' (ADU - baseline) at zero added light the model did not have. The camera conversion now
# keeps the read-noise floor and models it as background (engine.io.counts_to_photons).
def test_the_studio_reconstruction_of_a_noisy_image_is_not_empty(psf):
    _, result, _ = _run(psf, 1e6)
    assert result.ncc > 0.3 and result.f1 > 0.5


def test_reconstruction_is_scored_with_ncc_and_f1_beside_the_zero_floor(reconstructed):
    image, result, partials = reconstructed
    truth = image.ground_truth
    assert result.iterations == 6 and len(result.ncc_curve) == len(result.change_curve) == 6
    assert partials[-1] == (result.ncc_curve, result.change_curve)  # the live convergence curve is NCC
    assert result.ncc_curve[-1] == pytest.approx(float(ncc(truth, result.volume)), abs=1e-9)
    assert result.ncc == pytest.approx(result.ncc_curve[-1], abs=1e-12)
    assert result.ncc_curve[-1] > result.ncc_curve[0] and result.ncc > 0.3
    card = result.scores
    assert [s.key for s in card.scores] == ["ncc", "f1", "psnr_db", "ssim"] and card.peaks.reference == 3
    assert result.f1 == card.peaks.f1 and list(card.scores[0].floors) == ["zero"]
    assert result.psnr == card.score("psnr_db").value and result.ssim == card.score("ssim").value
    # The all-zero floor is the PSNR of an empty volume, computed here independently.
    zero_psnr = 10 * torch.log10(truth.double().max() ** 2 / truth.double().square().mean())
    assert card.score("psnr_db").floors["zero"] == pytest.approx(float(zero_psnr), abs=1e-9)
    assert result.summary.startswith(
        f"NCC {result.ncc:.3f}  F1 {result.f1:.2f} ({card.peaks.matched}/3 beads"
    )
    assert "PSNR" in result.summary and "(zero floor" in result.summary


def test_cells_are_not_scored_by_peaks():
    assert pipeline.peak_mode(WorkflowSettings(phantom="cells")) is False
    assert pipeline.peak_mode(WorkflowSettings(phantom="beads")) is True
    assert pipeline.peak_mode(WorkflowSettings(phantom="tiff")) is None  # judged from the volume


def test_quality_label_shows_ncc_and_f1_first_and_names_the_normalisation(qtbot, reconstructed):
    _, result, _ = reconstructed
    state = StudioState(small_fourier_design())
    panel = WorkflowPanel(state, reconstruction_available=True)
    qtbot.addWidget(panel)
    assert panel.quality.text() == NO_QUALITY
    state.set_reconstruction(result)
    assert panel.quality.text().startswith('<span style="color:#b35900;">stale: made with the previous')
    state.mark_fresh("reconstruction")  # what the controller does with a current result
    text = panel.quality.text()
    assert text == quality_text(result)
    assert text.startswith(f"<b>NCC {result.ncc:.3f}</b>&nbsp;&nbsp;&nbsp;<b>F1 {result.f1:.2f} (")
    assert f"&nbsp;PSNR {result.psnr:.2f} dB (zero floor" in text  # not bold: read after NCC and F1
    assert "least-squares scale matching" in text and "&lt;t, e&gt;" in text  # escaped, not eaten as HTML
    assert f"F1 {result.f1:.2f}" in text and "after 6 iterations" in text
    assert "zero floor" in panel.quality.toolTip()
    state.set_reconstruction(None)
    assert panel.quality.text() == NO_QUALITY
    panel.disconnect_state()


def test_quality_label_of_a_recorded_frame_says_it_has_no_ground_truth(reconstructed):
    _, result, _ = reconstructed
    raw = ReconstructionResult(result.volume, result.voxel_size, 6, method="rl-accelerated",
                               summary="measured frame: no ground truth to score against")  # fmt: skip
    text = quality_text(raw)
    assert text != NO_QUALITY and "–" not in text
    assert text == (
        "Reconstructed after 6 iterations. No scores: a recorded frame has no ground truth (NCC, F1, PSNR "
        "and SSIM compare a reconstruction with the phantom of a simulated image)."
    )


def test_convergence_plot_shows_ncc_against_the_zero_floor(qtbot, reconstructed):
    _, result, _ = reconstructed
    state = StudioState(small_fourier_design())
    plot = ConvergencePlot(state)
    qtbot.addWidget(plot)
    assert plot.plot.getPlotItem().getAxis("left").labelText == "NCC with the ground truth"
    assert plot.floor.value() == 0.0
    state.set_reconstruction(result)
    assert list(plot.curve.getData()[1]) == pytest.approx(list(result.ncc_curve))
    plot.disconnect_state()


def test_exported_metadata_carries_the_scores_and_floors(tmp_path, reconstructed):
    _, result, _ = reconstructed
    meta = {"iterations": result.iterations, **_scores_metadata(result.scores)}
    assert meta["ncc"] == result.ncc and meta["f1"] == result.f1 and meta["psnr_db"] == result.psnr
    assert meta["psnr_db_zero_floor"] == result.scores.score("psnr_db").floors["zero"]
    assert meta["peaks"]["reference"] == 3 and "scale matching" in meta["normalization"]
    write_volume(tmp_path / "v.tif", result.volume, voxel_size=result.voxel_size, metadata=meta)
    assert read_volume(tmp_path / "v.tif").metadata["ncc"] == pytest.approx(result.ncc)


def test_a_result_without_scores_still_shows_psnr_and_ssim():
    volume = torch.rand(2, 12, 12)
    text = quality_text(ReconstructionResult(volume, (1, 1, 1), 5, psnr=31.25, ssim=0.875))
    assert "PSNR 31.25 dB" in text and "SSIM 0.875" in text
    card = scorecard(volume, volume, peaks=False)
    assert card.score("f1") is None and "F1" not in card.summary()


def test_a_registered_method_is_in_the_studio_list_and_runs(psf, qtbot):
    from lfm_studio.engine.reconstruct import reconstruct_frame
    from tests import toy_method

    design, result = psf
    with toy_method.registered():
        state = StudioState(design)
        panel = WorkflowPanel(state)
        qtbot.addWidget(panel)
        offered = [panel.method.itemData(i) for i in range(panel.method.count())]
        assert offered[:4] == ["rl", "rl-accelerated", "wiener", "tikhonov"] and "backprojection" in offered
        assert state.workflow.method == "rl-accelerated" and panel.iterations.isEnabled()
        panel.method_options.set_method("backprojection")  # the user picks it: the settings follow
        assert state.workflow.method == "backprojection" and dict(state.workflow.method_options) == {
            "scale": 1.0
        }
        assert not panel.iterations.isEnabled() and panel.method_options.field("scale").isEnabled()
        assert state.stale >= {"reconstruction"}
        settings = replace(state.workflow, bead_count=3, photons=None, seed=1)
        image = pipeline.simulate_image(_ctx([]), design, result.stack, settings)
        partials: list = []
        got = pipeline.reconstruct(_ctx(partials), design, image, settings)
        direct = reconstruct_frame(image.setup.projector, image.counts, method="backprojection")
    assert got.method == "backprojection" and got.iterations == 0 and partials == []
    torch.testing.assert_close(got.volume, direct, rtol=1e-5, atol=1e-6 * float(direct.max()))
    assert got.ncc > 0.1  # measured about 0.2; a constant volume scores 0
    assert "(backprojection)" in quality_text(got) and "iterations" not in quality_text(got)


def test_a_one_step_method_that_needs_a_fourier_projector_is_refused_by_name():
    from lfm_studio.engine.reconstruct import get_method

    conventional = SimpleNamespace(setup=SimpleNamespace(projector=SimpleNamespace()))  # no OTF
    settings = WorkflowSettings(method="wiener")
    with pytest.raises(
        ValueError, match=r"method 'wiener' .* needs a laterally shift-invariant.*Fix: choose rl"
    ):
        pipeline.reconstruct(_ctx([]), None, conventional, settings)
    assert get_method("rl").supports(conventional.setup.projector)
