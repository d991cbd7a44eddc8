"""Scores that cannot be gamed: floors, the scorecard, and a real reconstruction beating
an all-zero, a constant and a voxel-shuffled volume on every default metric."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.image_quality import floor_volume, psnr, scorecard, shuffled, ssim
from lfm_studio.engine.reconstruct import richardson_lucy_iterates
from lfm_studio.engine.simulation import camera_of, light_field_image
from tests.engine.reconstruct.conftest import bead_phantom, make_conventional, make_fourier


def _sparse_truth() -> torch.Tensor:
    truth = torch.zeros(5, 24, 24, dtype=torch.float64)
    truth[1, 5, 5], truth[2, 15, 10], truth[3, 8, 20] = 4.0, 2.0, 3.0
    return truth


def test_psnr_floors_follow_closed_forms_and_the_normalisation_is_stated():
    truth = _sparse_truth()
    r = float(truth.max())  # min is 0
    card = scorecard(truth, 7.0 * truth, normalize="none")
    zero, constant = card.score("psnr_db").floors["zero"], card.score("psnr_db").floors["constant"]
    mean_square, variance = float(truth.square().mean()), float(truth.var(unbiased=False))
    assert zero == pytest.approx(10 * math.log10(r**2 / mean_square), abs=1e-9)
    assert constant == pytest.approx(10 * math.log10(r**2 / variance), abs=1e-9)
    # In the truth's units a 7x estimate is far off; after scale matching it is exact.
    assert card.score("psnr_db").value == pytest.approx(10 * math.log10(r**2 / (36 * mean_square)), abs=1e-9)
    assert card.score("psnr_db").margin < 0 and "truth's units" in card.normalization
    exact = scorecard(truth, 7.0 * truth, normalize="scale")
    assert exact.score("psnr_db").value == math.inf and exact.score("ssim").value == pytest.approx(1.0)
    assert "scale matching" in exact.normalization and "data range 4" in exact.normalization
    # The SSIM floors are the SSIM of the floor volumes themselves, on the same data range.
    assert exact.score("ssim").floors["zero"] == pytest.approx(
        float(ssim(truth, torch.zeros_like(truth), sigma=(0, 1.5, 1.5))), abs=1e-12
    )
    # A given data range moves every PSNR, floors too, by 20 log10(R'/R).
    moved = scorecard(truth, 7.0 * truth, normalize="none", data_range=40.0)
    assert moved.score("psnr_db").floors["zero"] == pytest.approx(zero + 20.0, abs=1e-9)
    assert float(psnr(truth, floor_volume("constant", truth))) == pytest.approx(constant, abs=1e-9)


def test_scorecard_order_table_summary_and_json():
    truth = _sparse_truth()
    estimate = truth + 0.005 * torch.rand(truth.shape, generator=torch.Generator().manual_seed(0))
    card = scorecard(truth, estimate, normalize="scale", voxel_size=(10e-6, 1e-6, 1e-6))
    assert [s.key for s in card.scores] == ["ncc", "f1", "psnr_db", "ssim"]  # auto: point-like truth
    assert card.peaks is not None and card.peaks.matched == 3 and card.peaks.unit == "um"
    for s in card.scores:
        assert s.margin == pytest.approx(s.value - max(s.floors.values()))
        assert s.floors["zero"] < s.value and s.floors["constant"] < s.value
    summary = card.summary(noun="beads")
    assert summary.startswith(f"NCC {card.score('ncc').value:.3f}  F1 1.00 (3/3 beads)  PSNR ")
    assert f"(zero floor {card.score('psnr_db').floors['zero']:.2f})" in summary
    table = card.table()
    assert table[0].split() == ["metric", "value", "zero", "floor", "constant", "floor", "margin"]
    assert [row.split()[0] for row in table[1:]] == ["NCC", "F1", "PSNR", "SSIM"]
    data = card.to_dict()
    assert data["ncc"] == card.score("ncc").value and data["peaks"]["f1"] == 1.0
    assert data["floors"]["zero"]["f1"] == 0.0 and data["floors"]["zero"]["ncc"] == 0.0
    assert data["normalize"] == "scale" and data["scores"][2]["metric"] == "psnr_db"
    assert scorecard(truth, estimate, peaks=False).score("f1") is None


def test_floors_and_shuffle():
    truth = _sparse_truth()
    assert floor_volume("zero", truth).abs().sum() == 0
    assert torch.allclose(floor_volume("constant", truth), torch.full_like(truth, float(truth.mean())))
    mixed = shuffled(truth, seed=1)
    assert not torch.equal(mixed, truth) and torch.equal(
        mixed.flatten().sort().values, truth.flatten().sort().values
    )
    with pytest.raises(ValueError, match="floor"):
        floor_volume("noise", truth)


SYSTEMS = {"fourier": (make_fourier, 10, 6), "conventional": (make_conventional, 3, 2)}


@pytest.fixture(scope="module", params=sorted(SYSTEMS))
def reconstructed(request):
    """A real case: beads imaged with noise through a small simulated system, 30 RL iterations."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small FFTs: 1 thread is faster on this CPU (docs/platform.md)
    try:
        build, count, seed = SYSTEMS[request.param]
        system = build()
        phantom = bead_phantom(system.setup, count=count, seed=seed)
        camera = camera_of(system.design)
        counts, _ = light_field_image(system.setup, phantom.data, camera, photons=2e5, seed=11)
        image = ((counts - camera.baseline) / camera.gain).clamp_min(0.0)
        *_, last = richardson_lucy_iterates(system.setup.projector, image, iterations=30)
    finally:
        torch.set_num_threads(threads)
    return phantom, last.estimate.double(), system.setup.voxel_size


def test_zero_constant_and_shuffled_volumes_score_clearly_below_a_reconstruction(reconstructed):
    phantom, estimate, voxel = reconstructed
    truth = phantom.data.double()

    def card(volume):
        return scorecard(truth, volume, normalize="scale", voxel_size=voxel)

    real = card(estimate)
    assert [s.key for s in real.scores] == ["ncc", "f1", "psnr_db", "ssim"]  # every default metric
    assert real.peaks.matched == phantom.count  # measured: every bead found, none false
    trivial = {
        "zero": torch.zeros_like(truth),
        "constant": torch.full_like(truth, float(truth.mean())),
    }
    # Measured (RL 30): NCC 0.87 / 0.76, F1 1.0, PSNR +6.0 / +3.8 dB and SSIM 0.995 / 0.985 against
    # the zero floor's 0.984 / 0.934 (Fourier 10 beads / conventional 3 beads).
    scores = {name: {s.key: s.value for s in card(volume).scores} for name, volume in trivial.items()}
    # A shuffled volume can land a peak near a bead by chance (3 depths: 2 voxels span them all),
    # so it is scored as the mean over 5 permutations (measured F1 0 to 0.5, mean 0.13).
    shuffles = [card(shuffled(estimate, seed=seed)).scores for seed in range(5)]
    scores["shuffled"] = {s.key: sum(c[i].value for c in shuffles) / 5 for i, s in enumerate(real.scores)}
    for name, value in scores.items():
        assert value["ncc"] < real.score("ncc").value - 0.5, name
        assert value["f1"] < real.score("f1").value - 0.5, name
        assert value["psnr_db"] < real.score("psnr_db").value - 3.0, name
        # SSIM of a sparse volume is near 1 for any flat guess: the reconstruction must close at
        # least half of the gap between the trivial volume's SSIM and 1.
        assert real.score("ssim").value - value["ssim"] > 0.5 * (1.0 - value["ssim"]), name
    # The floors the scorecard reports are the zero and constant volumes' own scores.
    for name in ("zero", "constant"):
        own = card(trivial[name])
        for s in real.scores:
            assert s.floors[name] == pytest.approx(own.score(s.key).value, abs=1e-12)
    assert real.peaks.rms_error < 1.0  # um; a wrong bead would be >= 2 voxels (1.4 um) off


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_scorecard_on_cuda_matches_cpu():
    truth = _sparse_truth()
    estimate = truth + 0.005 * torch.rand(truth.shape, generator=torch.Generator().manual_seed(0))
    cpu = scorecard(truth, estimate, normalize="scale").to_dict()
    gpu = scorecard(truth.cuda(), estimate.cuda(), normalize="scale").to_dict()
    for a, b in zip(cpu["scores"], gpu["scores"], strict=True):
        assert a["metric"] == b["metric"] and b["value"] == pytest.approx(a["value"], rel=1e-9, abs=1e-12)
