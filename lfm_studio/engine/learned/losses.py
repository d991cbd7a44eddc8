"""Training loss and the non-trivial-output check for learned reconstruction.

On sparse fluorescence an L1 loss collapses to the all-zero volume (docs/platform.md). The loss
here is an **energy-normalised MSE** ``|p - t|^2 / |t|^2`` (the all-zero prediction scores exactly
1, a perfect one 0) plus ``high_pass_weight`` times the same on a high-pass of both volumes
(each voxel minus its 3 x 3 x 3 mean), which rewards sharp, correctly placed objects over a
blurred average. Both terms are dimensionless.
"""

from __future__ import annotations

import torch
import torch.nn.functional as nnf

TRIVIAL_SPREAD = 1e-6
"""A volume whose standard deviation is below this fraction of its mean absolute value
(or that is all zero) is called constant."""


def energy_normalised_mse(prediction: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    """``sum (p - t)^2 / sum t^2`` (dimensionless; 1 for the all-zero prediction)."""
    energy = truth.pow(2).sum().clamp_min(torch.finfo(truth.dtype).tiny)
    return (prediction - truth).pow(2).sum() / energy


def high_pass(volume: torch.Tensor) -> torch.Tensor:
    """``volume`` minus its 3 x 3 x 3 local mean (replicate edges); shape ``(Z, Y, X)`` kept."""
    padded = nnf.pad(volume[None, None], (1, 1, 1, 1, 1, 1), mode="replicate")
    return volume - nnf.avg_pool3d(padded, 3, stride=1)[0, 0]


def training_loss(
    prediction: torch.Tensor, truth: torch.Tensor, high_pass_weight: float = 1.0
) -> torch.Tensor:
    """Energy-normalised MSE plus ``high_pass_weight`` x the same on :func:`high_pass` (all-zero: ``1 + w``)."""
    loss = energy_normalised_mse(prediction, truth)
    if high_pass_weight:
        loss = loss + high_pass_weight * energy_normalised_mse(high_pass(prediction), high_pass(truth))
    return loss


def trivial_reason(volume: torch.Tensor) -> str | None:
    """Why ``volume`` is a trivial answer ("all zero", "constant", "not finite"), or None."""
    values = volume.detach().double()
    if not bool(torch.isfinite(values).all()):
        return "not finite"
    scale = float(values.abs().mean())
    if scale == 0.0:
        return "all zero"
    if float(values.std()) <= TRIVIAL_SPREAD * scale:
        return "constant"
    return None


def require_not_trivial(volume: torch.Tensor, what: str) -> torch.Tensor:
    """``volume`` unchanged, or ValueError when it is all zero, constant or not finite."""
    reason = trivial_reason(volume)
    if reason is not None:
        raise ValueError(
            f"{what} is {reason}: a collapsed model. Fix: train longer or with more photons, or check "
            "that the training data match the design (lfm-studio train --help)."
        )
    return volume
