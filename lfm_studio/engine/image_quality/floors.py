"""Trivial volumes that every score must be read against ("floors").

A score means something only next to what a volume with no information gets on the
same truth. For a sparse phantom (a few beads in an empty volume) the all-zero volume
already scores a high PSNR and an SSIM near 1, because nearly every voxel of the truth
is zero; a reconstruction that beats it by a fraction of a dB has found little.

- ``"zero"``: the all-zero volume.
- ``"constant"``: every voxel at the truth's mean (the constant with the smallest squared
  error, so the strongest constant guess in the truth's units).
- :func:`shuffled`: the estimate's own voxels in a random order (same histogram, no
  structure); used by the tests as a third floor.

Floors are scored exactly like the estimate (same normalisation, data range and peak
settings), see :func:`lfm_studio.engine.image_quality.scorecard.scorecard`.
"""

from __future__ import annotations

import torch

FLOORS: tuple[str, ...] = ("zero", "constant")
"""The floors ``lfm-studio metrics`` prints beside each score."""


def floor_volume(name: str, truth: torch.Tensor) -> torch.Tensor:
    """The floor volume ``name`` ("zero" or "constant") on the grid of ``truth`` (float64)."""
    truth = torch.as_tensor(truth).detach()
    if name == "zero":
        return torch.zeros(truth.shape, dtype=torch.float64, device=truth.device)
    if name == "constant":
        return torch.full(truth.shape, float(truth.double().mean()), dtype=torch.float64, device=truth.device)
    raise ValueError(f"floor must be one of {FLOORS}; got {name!r}.")


def shuffled(volume: torch.Tensor, seed: int = 0) -> torch.Tensor:
    """``volume`` with its voxels permuted by a seeded random permutation (same shape and values)."""
    volume = torch.as_tensor(volume).detach()
    generator = torch.Generator().manual_seed(int(seed))
    order = torch.randperm(volume.numel(), generator=generator).to(volume.device)
    return volume.reshape(-1)[order].reshape(volume.shape)
