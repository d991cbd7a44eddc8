"""Unrolled Richardson-Lucy: K physics steps with the design's projector and a small learned
correction after each (the default learned model; a few thousand parameters).

Step ``k``: the Richardson-Lucy update ``x <- x * r^{a_k}``, ``r = A^T(y / (A x + b)) / A^T 1``, with
the design's own projector ``A`` and a learnable exponent ``a_k`` (started at 1: plain RL; an
exponent above 1 takes a longer step along the same multiplicative direction, the classic way to
accelerate RL, so a few unrolled steps can do the work of many plain ones), then ``x <- x * exp(a tanh(c_k(log(1 + x / mean x))))`` where ``c_k`` is a
two-layer 3-D convolution (``hidden`` channels, 3 x 3 x 3) and ``a`` bounds the change per step
(``max_log_change``). The last layer of every ``c_k`` starts at zero, so an untrained model is
exactly ``iterations`` plain RL iterations from a flat start; training can only move it from
there. Multiplicative steps keep the volume non-negative.

Read noise (``read_noise`` sigma, photo-electrons rms): the shifted-Poisson approximation of
Snyder et al. (1993) adds ``sigma^2`` to the image and to ``A x + b`` (``y + sigma^2`` is nearly
Poisson with mean ``A x + b + sigma^2``). Clipping the noisy image at 0 instead, as before, added a
positive bias of about ``0.4 sigma`` per pixel that RL explained with light: on a 2048^2 FLFM at 1e5
photons per image, 30 plain RL steps scored a validation loss of 42.6 (all-zero volume: 2.0), and
0.97 with the shift. :func:`~lfm_studio.engine.learned.train.train` sets it from the training data's
read noise; checkpoints without it (older ones) run with 0, as they were trained.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from lfm_studio.engine.learned.models.common import (
    adjoint_normaliser,
    differentiable_normaliser,
    image_scale,
    projector_dtype,
)
from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.reconstruct.unrolled import rl_ratio

EXPONENT_RATE = 10.0
"""The exponent is ``exp(EXPONENT_RATE * p)`` for a parameter ``p`` started at 0: an Adam step of
about the learning rate then moves the exponent by about ten times as much as a convolution
weight, so the step lengths adapt within a short training run."""


class _Correction(nn.Module):
    def __init__(self, hidden: int, max_log_change: float) -> None:
        super().__init__()
        self.inner = nn.Conv3d(1, hidden, 3, padding=1)
        self.outer = nn.Conv3d(hidden, 1, 3, padding=1)
        nn.init.zeros_(self.outer.weight)
        if self.outer.bias is not None:
            nn.init.zeros_(self.outer.bias)
        self.max_log_change = max_log_change

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        features = torch.log1p(x / x.mean().clamp_min(torch.finfo(x.dtype).tiny))[None, None]
        change = self.outer(torch.relu(self.inner(features)))[0, 0]
        return x * torch.exp(self.max_log_change * torch.tanh(change))


class UnrolledRL(nn.Module):
    """``iterations`` RL steps through ``projector``, each followed by a learned correction.

    Parameters
    ----------
    projector : the design's projector (forward/adjoint on ``(Z, Vy, Vx)`` / ``(Py, Px)``).
    iterations : physics steps K.
    hidden : channels of each correction.
    max_log_change : bound of one correction's log-change per voxel.
    background : expected background per pixel, photons.
    read_noise : camera read noise, photo-electrons rms (the shifted-Poisson ``sigma``; 0 = none).
    """

    def __init__(
        self,
        projector: Projector,
        *,
        iterations: int = 6,
        hidden: int = 6,
        max_log_change: float = 1.0,
        background: float = 0.0,
        read_noise: float = 0.0,
    ) -> None:
        super().__init__()
        if not (isinstance(iterations, int) and iterations >= 1):
            raise ValueError(f"iterations must be an integer >= 1; got {iterations!r}.")
        if not (isinstance(read_noise, (int, float)) and math.isfinite(read_noise) and read_noise >= 0):
            raise ValueError(
                f"read_noise must be >= 0 photo-electrons rms; got {read_noise!r}. Fix: e.g. 1.0."
            )
        self.projector = projector
        self.config = {"iterations": iterations, "hidden": hidden, "max_log_change": max_log_change,
                       "background": background}  # fmt: skip
        if read_noise:  # absent from the config (and the checkpoint) when 0, as in older checkpoints
            self.config["read_noise"] = float(read_noise)
        self.norm: torch.Tensor
        self.register_buffer("norm", adjoint_normaliser(projector), persistent=False)
        self.steps = nn.ModuleList(_Correction(hidden, max_log_change) for _ in range(iterations))
        self.log_exponents = nn.Parameter(torch.zeros(iterations))
        self.to(projector_dtype(projector))

    def forward(self, image: torch.Tensor, projector: Projector | None = None) -> torch.Tensor:
        """The volume reconstructed from ``image``; ``projector`` replaces the stored one for this call
        (end-to-end optics optimisation: a projector whose PSF carries gradients, with the same
        volume and image shapes; its sensitivity ``A^T 1`` is then computed with gradients)."""
        if projector is None:
            projector, norm = self.projector, self.norm
        else:
            norm = differentiable_normaliser(projector)
        shift = float(self.config.get("read_noise", 0.0)) ** 2  # shifted Poisson (module docstring)
        y = image.to(norm.dtype).clamp_min(-shift) + shift  # >= 0: RL needs non-negative data
        scale = image_scale(y)
        y = y / scale
        background = (self.config["background"] + shift) / scale
        tiny = torch.finfo(y.dtype).eps
        signal = (y.sum() - background * y.numel()).clamp_min(tiny * y.sum())
        x = torch.ones_like(norm) * (signal / norm.sum())  # flat start (keeps the graph to y)
        for step, log_exponent in zip(self.steps, self.log_exponents, strict=True):
            ratio = rl_ratio(projector, y, x, norm, background=background)
            x = step(x * ratio.clamp_min(tiny) ** torch.exp(EXPONENT_RATE * log_exponent))
        return x * scale
