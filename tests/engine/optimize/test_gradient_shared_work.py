"""The gradient optimisers do each start evaluation once: end-to-end computes the start PSF once
(model, grid and start held-out loss share it), and the float32 / float64 start-gradient check
takes the run's own precision from the first step's gradient (same point, batch and weights)
instead of evaluating it again. Counted through ``SpaceBinding.psf_stack``; the check's numbers
equal those of a check that evaluates both precisions itself."""

from __future__ import annotations

import warnings

import pytest
import torch

from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optimize import end_to_end, gradient
from lfm_studio.engine.optimize.gradient_params import SpaceBinding

from .test_gradient_psf import SETTINGS, SPACE, poor_start  # noqa: F401 - poor_start: a fixture

E2E = dict(lr=0.1, settings=SETTINGS, constraints=(), batch=1, held_out=1, iterations=2, steps=1)


@pytest.fixture
def psf_calls(monkeypatch):
    """The precision of every PSF stack the optimisers compute."""
    calls: list[str] = []
    original = SpaceBinding.psf_stack

    def counted(self, design, values, settings):
        calls.append(settings.dtype)
        return original(self, design, values, settings)

    monkeypatch.setattr(SpaceBinding, "psf_stack", counted)
    return calls


class _BothPrecisions(gradient.StartGradientCheck):
    """The check as it was: both precisions evaluated at the start, nothing taken from step 0."""

    def __init__(self, loss, dtype, tolerance, *, reuse):
        super().__init__(loss, dtype, tolerance, reuse=False)


def _quiet(run, *args, **kwargs):
    torch.manual_seed(0)  # the unrolled-RL weights start random
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        return run(*args, **kwargs)


def test_end_to_end_computes_the_start_psf_once_and_takes_the_float32_check_from_step_0(
    poor_start,  # noqa: F811 - the fixture imported above
    psf_calls,
    monkeypatch,
):
    reused = _quiet(end_to_end.optimize_end_to_end, poor_start, SPACE, **E2E)
    # the start (model, grid, held-out loss), the check's float64 half, step 0, the final held-out loss
    assert psf_calls == ["float32", "float64", "float32", "float32"]
    psf_calls.clear()
    monkeypatch.setattr(end_to_end, "StartGradientCheck", _BothPrecisions)
    both = _quiet(end_to_end.optimize_end_to_end, poor_start, SPACE, **E2E)
    assert psf_calls == ["float32", "float32", "float64", "float32", "float32"]
    assert reused.check is not None and reused.check.to_dict() == both.check.to_dict()
    assert (
        reused.summary() == both.summary() and reused.extra["held_out_start"] == both.extra["held_out_start"]
    )


def test_a_frozen_reconstruction_is_checked_in_both_precisions_at_the_start(
    poor_start,  # noqa: F811 - the fixture imported above
    psf_calls,
):
    """Step 0 does not differentiate frozen weights, so it cannot stand in for the check's float32 half."""
    result = _quiet(end_to_end.optimize_end_to_end, poor_start, SPACE, freeze_reconstruction=True, **E2E)
    assert psf_calls == ["float32", "float32", "float64", "float32", "float32"]
    assert result.check is not None and len(result.check.gradient_float32) > 2  # the weights' gradients too


def test_psf_engineering_takes_the_check_in_its_precision_from_the_first_step(
    poor_start,  # noqa: F811 - the fixture imported above
    psf_calls,
    monkeypatch,
):
    options = dict(settings=SETTINGS, constraints=(), lr=0.1, steps=2)
    reused = _quiet(gradient.optimize_psf, poor_start, SPACE, "axial_crb", **options)
    assert psf_calls == ["float64", "float32", "float32", "float32"]  # check float64, 2 steps, the last point
    psf_calls.clear()
    monkeypatch.setattr(gradient, "StartGradientCheck", _BothPrecisions)
    both = _quiet(gradient.optimize_psf, poor_start, SPACE, "axial_crb", **options)
    assert psf_calls == ["float32", "float64", "float32", "float32", "float32"]
    assert reused.check is not None and reused.check.to_dict() == both.check.to_dict()
    assert reused.summary() == both.summary()
