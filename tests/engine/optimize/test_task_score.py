"""Task score (objective c): held-out phantoms imaged and reconstructed; trivial volumes score at the floor."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.optimize import Candidate, EvaluationSettings, TaskScore, objective_named, score_volume
from lfm_studio.engine.phantoms import beads

from .conftest import small


@pytest.fixture(scope="module")
def candidate():
    """FLFM on a 256 px sensor (outer sub-images cut), 5 depths 10 um apart."""
    design = small("flfm_guo2019", 256, (-20.0, 20.0), 10.0)
    return Candidate(design, EvaluationSettings(crop=None))


def test_score_volume_floors_on_constructed_volumes():
    voxel = (10e-6, 1e-6, 1e-6)
    truth = beads((5, 40, 40), count=8, voxel_size=voxel, seed=3).data
    reference = (truth > 0).nonzero()
    zero = torch.zeros_like(truth)
    constant = torch.full_like(truth, float(truth.mean()))
    assert score_volume("ncc", truth, truth) == pytest.approx(1.0)
    assert score_volume("ncc", truth, zero) == 0.0 and score_volume("ncc", truth, constant) == 0.0
    assert score_volume("f1", truth, truth, reference=reference) == 1.0
    assert score_volume("f1", truth, zero, reference=reference) == 0.0
    # Localisation: 0 um for the truth, the worst (tolerance x coarsest voxel = 2 x 10 um) for nothing.
    assert score_volume("localisation", truth, truth, reference=reference, voxel_size=voxel) == 0.0
    assert score_volume("localisation", truth, zero, reference=reference, voxel_size=voxel) == pytest.approx(
        20.0
    )
    # Three beads found one voxel off along x (1 um) and one bead missed: (3 x 1 + 20) / 4 um.
    points = torch.zeros((5, 40, 40))
    found = torch.zeros((5, 40, 40))
    for z, y, x in ((1, 10, 10), (2, 20, 30), (3, 30, 15), (4, 5, 35)):
        points[z, y, x] = 1.0
    for z, y, x in ((1, 10, 11), (2, 20, 31), (3, 30, 16)):
        found[z, y, x] = 1.0
    where = (points > 0).nonzero()
    assert score_volume("localisation", points, found, reference=where, voxel_size=voxel) == pytest.approx(
        23 / 4
    )
    assert score_volume("f1", points, found, reference=where) == pytest.approx(6 / 7)
    # OSPA: the same plus two false peaks far from any bead: (3 x 1 + 20 x (5 - 3)) / 5 um; a noise
    # volume with a peak beside every bead and many more elsewhere scores near the worst, 20 um.
    found[0, 38, 2] = found[4, 2, 20] = 1.0
    assert score_volume("localisation", points, found, reference=where, voxel_size=voxel) == pytest.approx(
        43 / 5
    )
    noise = torch.rand((5, 40, 40), generator=torch.Generator().manual_seed(4))
    noisy = score_volume("localisation", points, noise, reference=where, voxel_size=voxel)
    assert noisy > 0.9 * 20.0
    with pytest.raises(ValueError, match="task metric"):
        score_volume("psnr", truth, truth)


def test_task_scores_beat_the_all_zero_floor(candidate):
    ncc = TaskScore("ncc", iterations=15, photons=1e5, seeds=(1000,))
    f1 = TaskScore("f1", iterations=15, photons=1e5, seeds=(1000,))
    loc = TaskScore("localisation", iterations=15, photons=1e5, seeds=(1000,))
    real = {s.name: s(candidate) for s in (ncc, f1, loc)}
    truth, estimate, reference = ncc.trial(candidate, 1000)
    assert estimate.shape == truth.shape == candidate.setup.volume_shape
    zero = torch.zeros_like(truth)
    voxel = candidate.setup.voxel_size
    floors = {
        "task_ncc": score_volume("ncc", truth, zero),
        "task_f1": score_volume("f1", truth, zero, reference=reference),
        "task_localisation": score_volume("localisation", truth, zero, reference=reference, voxel_size=voxel),
    }
    assert floors == {
        "task_ncc": 0.0,
        "task_f1": 0.0,
        "task_localisation": pytest.approx(2 * max(voxel) * 1e6),
    }
    assert real["task_ncc"] > 0.3 > floors["task_ncc"]
    assert real["task_f1"] > 0.5 > floors["task_f1"]
    assert real["task_localisation"] < 0.5 * floors["task_localisation"]
    # One reconstruction per seed serves every task metric; stages are timed.
    assert len([k for k in candidate.memo if k[0] == "task"]) == 1
    assert candidate.timing["reconstruct_s"] > 0 and candidate.timing["psf_s"] > 0


def test_fewer_photons_score_lower(candidate):
    """A 100x smaller photon budget must not score better (same phantoms, same noise seeds)."""
    bright = TaskScore("ncc", iterations=15, photons=1e5, seeds=(1000, 1001))(candidate)
    dim = TaskScore("ncc", iterations=15, photons=1e3, seeds=(1000, 1001))(candidate)
    assert dim < bright


def test_registered_task_objectives_take_run_options():
    score = objective_named(
        "task_f1", {"photons": 5e4, "iterations": 7, "method": "rl-accelerated", "ignored": 1}
    )
    assert (score.name, score.unit, score.direction) == ("task_f1", "", "maximize")
    assert (score.photons, score.iterations, score.method) == (5e4, 7, "rl-accelerated")
    assert objective_named("task_localisation").direction == "minimize"
    with pytest.raises(ValueError, match="method"):
        TaskScore(method="magic")
    with pytest.raises(ValueError, match="objective must be one of"):
        objective_named("sharpness")
