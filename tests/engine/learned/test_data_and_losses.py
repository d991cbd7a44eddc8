"""Training data (seeded, disjoint splits, photon budget) and the loss floors."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.learned.data import SPLIT_SIZE, TrainingDataSpec, make_sample, sample_seed
from lfm_studio.engine.learned.losses import (
    energy_normalised_mse,
    require_not_trivial,
    training_loss,
    trivial_reason,
)


def test_samples_are_reproducible_and_splits_never_share_a_seed(fourier):
    spec = TrainingDataSpec(seed=3)
    a, b = make_sample(spec, fourier.setup, "train", 5), make_sample(spec, fourier.setup, "train", 5)
    assert torch.equal(a.image, b.image) and torch.equal(a.truth, b.truth)  # same seed, same path
    assert not torch.equal(a.image, make_sample(spec, fourier.setup, "validation", 5).image)
    seeds = {split: {sample_seed(spec, split, i) for i in (0, 1, SPLIT_SIZE - 1)}
             for split in ("train", "validation", "test")}  # fmt: skip
    assert not (
        seeds["train"] & seeds["validation"]
        or seeds["train"] & seeds["test"]
        or seeds["validation"] & seeds["test"]
    )
    other = {sample_seed(TrainingDataSpec(seed=4), "train", i) for i in (0, SPLIT_SIZE - 1)}
    assert not other & set().union(*seeds.values())
    with pytest.raises(ValueError, match="index must be in"):
        sample_seed(spec, "train", SPLIT_SIZE)


@pytest.mark.parametrize("photons", [1e3, 1e5])
def test_an_image_holds_the_photon_budget_up_to_its_noise(fourier, photons):
    spec = TrainingDataSpec(photons=(photons,), read_noise=2.0, phantoms="beads")
    sample = make_sample(spec, fourier.setup, "test", 0)
    pixels = sample.image.numel()
    spread = math.sqrt(photons + pixels * spec.read_noise**2)  # Poisson + read noise of the sum
    assert abs(float(sample.image.double().sum()) - photons) < 5 * spread
    assert sample.truth.shape == tuple(fourier.setup.volume_shape) and float(sample.truth.min()) >= 0
    # The truth is in photons emitted per voxel: its image through the projector holds the budget.
    expected = fourier.setup.projector.forward(sample.truth)
    assert float(expected.double().sum()) == pytest.approx(photons, rel=1e-4)


def test_spec_round_trips_and_refuses_bad_values():
    spec = TrainingDataSpec(phantoms="cells", objects=(2, 3), photons=(1e4,), seed=9)
    assert TrainingDataSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ValueError, match="phantoms must be"):
        TrainingDataSpec(phantoms="stars")
    with pytest.raises(ValueError, match="photons must be positive"):
        TrainingDataSpec(photons=(0.0,))


def test_the_loss_puts_the_all_zero_volume_at_its_floor_and_a_perfect_one_at_zero():
    truth = torch.zeros(3, 9, 9)
    truth[1, 4, 4], truth[2, 2, 6] = 5.0, 2.0
    for weight in (0.0, 1.0):
        assert float(training_loss(torch.zeros_like(truth), truth, weight)) == pytest.approx(1.0 + weight)
        assert float(training_loss(truth, truth, weight)) == 0.0
    blurred = torch.nn.functional.avg_pool3d(truth[None, None], 3, stride=1, padding=1)[0, 0]
    best_scale = float((blurred * truth).sum() / (blurred * blurred).sum())
    # A blurred answer at its best scale beats zero on the plain MSE but the high-pass term still sees the blur.
    assert float(energy_normalised_mse(blurred * best_scale, truth)) < 1.0
    assert float(training_loss(blurred * best_scale, truth, 1.0)) > float(
        energy_normalised_mse(blurred * best_scale, truth)
    )


def test_trivial_outputs_are_named():
    assert trivial_reason(torch.zeros(2, 3, 3)) == "all zero"
    assert trivial_reason(torch.full((2, 3, 3), 4.0)) == "constant"
    assert trivial_reason(torch.tensor([1.0, math.nan])) == "not finite"
    assert trivial_reason(torch.tensor([0.0, 1.0])) is None
    with pytest.raises(ValueError, match="is all zero: a collapsed model"):
        require_not_trivial(torch.zeros(3), "the output")


def test_samples_are_cpu_tensors_drawn_with_the_cpu_generator(fourier, conventional):
    """The noise is drawn on the CPU (a seeded CPU generator cannot draw on a CUDA tensor) and the
    sample comes back on the CPU whatever the projector's device; this machine has no GPU, so
    the path is run with device "cpu" (the CUDA path differs only by the moves)."""
    spec = TrainingDataSpec(seed=2, read_noise=1.0, phantoms="mix")
    for system in (fourier, conventional):
        assert system.setup.projector.device == torch.device("cpu")
        sample = make_sample(spec, system.setup, "train", 1)
        assert sample.image.device.type == "cpu" and sample.truth.device.type == "cpu"
        assert sample.image.dtype == torch.float32 and bool(torch.isfinite(sample.image).all())
        again = make_sample(spec, system.setup, "train", 1)
        assert torch.equal(sample.image, again.image)
