"""reconstruct_frame: each method name runs what it says (same result as the direct call)."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.reconstruct import (
    accelerated_rl_options,
    reconstruct_frame,
    richardson_lucy,
    tikhonov,
    wiener,
)
from tests.engine.reconstruct.conftest import bead_phantom


@pytest.fixture(scope="module")
def frame(fourier):
    truth = bead_phantom(fourier.setup, count=3, seed=6).data
    return fourier.setup.projector.forward(truth).clamp_min(0.0) + 2.0


def test_each_method_name_gives_the_direct_call(fourier, frame):
    projector = fourier.setup.projector
    signal = frame - 2.0  # not clipped: the linear methods invert the frame minus the background
    expected = {
        "rl": (richardson_lucy(projector, frame, background=2.0, iterations=4), {"iterations": 4}),
        "rl-accelerated": (
            richardson_lucy(
                projector, frame, background=2.0, iterations=4, **accelerated_rl_options(projector)
            ),
            {"iterations": 4},
        ),
        "wiener": (wiener(projector, signal, snr=50.0), {"snr": 50.0}),
        "tikhonov": (tikhonov(projector, signal, mu=1.0 / 50.0), {"snr": 50.0}),
    }
    for method, (reference, options) in expected.items():
        got = reconstruct_frame(projector, frame, method=method, background=2.0, **options)
        torch.testing.assert_close(got, reference, rtol=1e-6, atol=1e-6 * float(reference.abs().max()))
    # The accelerated method is a different algorithm, not plain RL under another name.
    assert not torch.allclose(expected["rl"][0], expected["rl-accelerated"][0])


def test_an_unknown_method_is_named(fourier, frame):
    with pytest.raises(ValueError, match=r"method must be one of .*'nesterov'"):
        reconstruct_frame(fourier.setup.projector, frame, method="nesterov")


def test_an_option_the_method_does_not_take_is_named(fourier, frame):
    with pytest.raises(
        ValueError, match=r"method 'wiener' takes no option 'iterations'; its options are background, snr"
    ):
        reconstruct_frame(fourier.setup.projector, frame, method="wiener", iterations=4)
