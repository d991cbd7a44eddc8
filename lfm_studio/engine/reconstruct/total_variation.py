"""Total-variation regularised Richardson-Lucy (Dey et al., Microsc. Res. Tech. 69, 260, 2006).

The RL update is divided by ``1 - lambda div(grad x / |grad x|)`` evaluated at the
current estimate (the gradient of the TV term of the penalised likelihood):

    x_{k+1} = x_k / (1 - lambda div(grad x_k / |grad x_k|)) * A^T(y / (A x_k + b)) / A^T 1

Gradients are forward differences over the three voxel axes (Z, Y, X, in voxel units)
with zero flux at the far edges; the divergence is minus their adjoint (backward
differences). ``|grad x|`` is smoothed by an epsilon relative to the estimate's scale.

Guard: every component of the unit field ``n = grad x / |grad x|`` is in ``[-1, 1]``
and ``sum_a n_a`` at one voxel is at most ``sqrt(3)`` in size, so
``|div n| <= 3 + sqrt(3)``. A weight ``lambda < 1 / (3 + sqrt(3)) = 0.211`` therefore
keeps the denominator above ``1 - lambda (3 + sqrt(3)) > 0``: larger weights are
rejected up front (Dey et al. use ``lambda`` of about 0.002). The denominator is also
floored as every RL division is.
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.reconstruct.guards import relative_floor

DIVERGENCE_BOUND = 3.0 + math.sqrt(3.0)  # max |div(grad x / |grad x|)| over three axes
MAX_TV_WEIGHT = 1.0 / DIVERGENCE_BOUND


def check_tv_weight(weight: float) -> float:
    """``weight`` as a float in ``[0, 1 / (3 + sqrt 3))``, else a ``ValueError`` with the limit."""
    value = float(weight)
    if not (0.0 <= value < MAX_TV_WEIGHT):
        raise ValueError(
            f"tv_weight must be in [0, {MAX_TV_WEIGHT:.4f}) so that 1 - tv_weight * div(...) stays > 0 "
            f"(|div| <= 3 + sqrt(3)); got {weight!r}. Fix: use a small weight, typically 0.001 to 0.02, "
            "or 0 for no regularisation."
        )
    return value


def _forward_difference(x: torch.Tensor, dim: int) -> torch.Tensor:
    diff = torch.diff(x, dim=dim)
    pad = [0, 0] * (x.ndim - 1 - dim) + [0, 1]  # zero flux through the far edge
    return torch.nn.functional.pad(diff, pad)


def _backward_difference(p: torch.Tensor, dim: int) -> torch.Tensor:
    shifted = torch.nn.functional.pad(
        p.narrow(dim, 0, p.shape[dim] - 1), [0, 0] * (p.ndim - 1 - dim) + [1, 0]
    )
    return p - shifted


def tv_divergence(x: torch.Tensor) -> torch.Tensor:
    """``div(grad x / |grad x|)`` for a volume ``(Z, Y, X)`` (voxel units), same shape."""
    grads = [_forward_difference(x, dim) for dim in range(3)]
    scale = float(x.detach().abs().max()) or 1.0
    eps = relative_floor(x.dtype) * scale
    gz, gy, gx = grads
    magnitude = torch.sqrt(gz * gz + gy * gy + gx * gx + eps * eps)
    return (
        _backward_difference(gz / magnitude, 0)
        + _backward_difference(gy / magnitude, 1)
        + _backward_difference(gx / magnitude, 2)
    )


def tv_denominator(x: torch.Tensor, weight: float) -> torch.Tensor:
    """``1 - weight * div(grad x / |grad x|)``, >= ``1 - weight (3 + sqrt 3)`` > 0 for a checked weight."""
    denominator = 1.0 - weight * tv_divergence(x)
    return denominator.clamp_min(1.0 - weight * DIVERGENCE_BOUND)
