"""CPU = CUDA for every reconstruction method (skipped without a GPU)."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.reconstruct import (
    richardson_lucy,
    tikhonov,
    wiener,
    wiener_butterworth_backprojector,
)
from lfm_studio.engine.systems.conventional_psf import lattice_projector
from tests.engine.reconstruct.conftest import bead_phantom

pytestmark = [pytest.mark.cuda, pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")]

# float64 on both devices: cuFFT and MKL/pocketfft round differently, ~1e-15 per pass, amplified
# a little by 20 multiplicative updates; 1e-9 relative leaves a wide margin.
TOLERANCE = 1e-9


def _close(cpu: torch.Tensor, cuda: torch.Tensor) -> bool:
    assert cuda.device.type == "cuda"
    return float((cuda.cpu() - cpu).norm() / cpu.norm()) < TOLERANCE


@pytest.mark.parametrize(
    "options",
    [
        {},
        {"acceleration": "biggs-andrews"},
        {"acceleration": "geometric"},
        {"backprojector": "wb"},
        {"tv_weight": 0.01},
    ],
    ids=["plain", "biggs-andrews", "geometric", "wiener-butterworth", "tv"],
)
def test_fourier_richardson_lucy_cpu_equals_cuda(fourier, options):
    cpu_projector = fourier.setup64.projector
    cuda_projector = ShiftInvariantProjector(fourier.stack.data.double().cuda(), cpu_projector.lateral_shape)
    truth = bead_phantom(fourier.setup, count=3, seed=6).data.double()
    image = cpu_projector.forward(truth).clamp_min(0.0)
    results = []
    for projector in (cpu_projector, cuda_projector):
        extra = dict(options)
        if extra.get("backprojector") == "wb":
            extra["backprojector"] = wiener_butterworth_backprojector(projector)
        results.append(richardson_lucy(projector, image.to(projector.device), iterations=20, **extra))
    assert _close(*results)


def test_conventional_richardson_lucy_cpu_equals_cuda(conventional):
    cpu_projector = conventional.setup64.projector
    cuda_projector = lattice_projector(conventional.stack.to(device="cuda"))
    truth = bead_phantom(conventional.setup, count=3, seed=2).data.double()
    image = cpu_projector.forward(truth).clamp_min(0.0)
    cpu = richardson_lucy(cpu_projector, image, iterations=20, acceleration="biggs-andrews")
    assert _close(
        cpu, richardson_lucy(cuda_projector, image.cuda(), iterations=20, acceleration="biggs-andrews")
    )


@pytest.mark.parametrize(
    "method", [lambda p, y: wiener(p, y, snr=50.0), lambda p, y: tikhonov(p, y, refine=3)]
)
def test_linear_methods_cpu_equal_cuda(fourier, method):
    cpu_projector = fourier.setup64.projector
    cuda_projector = ShiftInvariantProjector(fourier.stack.data.double().cuda(), cpu_projector.lateral_shape)
    truth = bead_phantom(fourier.setup, count=3, seed=6).data.double()
    image = cpu_projector.forward(truth)
    assert _close(method(cpu_projector, image), method(cuda_projector, image.cuda()))
