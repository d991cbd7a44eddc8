"""Compute one PSF stack of a bench case with given engine options (timed by the caller)."""

from __future__ import annotations

import warnings

import torch

from lfm_studio.bench.cases import BenchCase
from lfm_studio.bench.knobs import EngineOptions
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.conventional_psf import conventional_psf_stack
from lfm_studio.engine.systems.fourier_psf import FourierAccuracy, fourier_psf_stack
from lfm_studio.engine.systems.from_design import conventional_system_of, fourier_system_of


def compute_stack(case: BenchCase, options: EngineOptions) -> tuple[PSFStack, list[str]]:
    """The PSF stack of ``case`` at ``options`` (CPU) and the warnings the engine raised.

    Warnings (e.g. a ``SamplingWarning`` for too few Debye nodes) are recorded, not
    raised: the sweep measures what such a setting costs in error.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if isinstance(options, FourierAccuracy):
            stack = fourier_psf_stack(fourier_system_of(case.design), case.depths, accuracy=options)
        else:
            stack = conventional_psf_stack(conventional_system_of(case.design), case.depths, accuracy=options)
    messages = sorted({f"{w.category.__name__}: {str(w.message).split('.')[0]}" for w in caught})
    return stack, messages


def depth_first(stack: PSFStack) -> torch.Tensor:
    """Stack data with depth as the first axis, float64: ``(Z, H, W)`` or ``(Z, S, S, H, H)``."""
    data = stack.data.detach().to("cpu", torch.float64)
    return data if data.ndim == 3 else data.movedim(2, 0)


def reference_stack(case: BenchCase, plan: list[tuple[EngineOptions, float]]) -> PSFStack:
    """``sum(weight * stack)`` over ``plan`` (float64, clipped at 0: an extrapolated pixel
    integral can dip below 0 by rounding in the dark tails)."""
    total = None
    first = None
    for options, weight in plan:
        stack, _ = compute_stack(case, options)
        data = stack.data.detach().to("cpu", torch.float64) * weight
        total = data if total is None else total + data
        first = first or stack
    assert first is not None and total is not None
    return first.with_data(total.clamp_min(0.0))
