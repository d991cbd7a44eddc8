"""Pearson correlation (zero-shift normalised cross-correlation) of an estimate with the truth.

``NCC = sum((t - mean t)(e - mean e)) / sqrt(sum((t - mean t)^2) sum((e - mean e)^2))``,
accumulated in float64. It ignores the estimate's absolute scale and offset (a
reconstruction in other units scores the same), lies in ``[-1, 1]``, and a volume
without structure scores 0: the all-zero and every constant volume (whose variance is
zero, so the formula is 0 / 0) are defined to score exactly 0, and a voxel-shuffled
volume scores about 0. It is the first number to read for a sparse phantom, where PSNR
and SSIM of the empty background flatter any estimate (see :mod:`.floors`).
"""

from __future__ import annotations

import torch

from lfm_studio.engine.image_quality.basic import as_pair


def ncc(truth, estimate) -> torch.Tensor:
    """Pearson correlation of ``estimate`` with ``truth`` over all voxels (0-d float64 tensor).

    Parameters
    ----------
    truth, estimate : real tensors or arrays of one shape (images or volumes, any units).

    Returns
    -------
    The correlation in ``[-1, 1]``; exactly 0 when either input is constant (no structure
    to correlate). Differentiable in ``estimate`` where it is not constant.
    """
    truth, estimate = as_pair(truth, estimate, name="ncc")
    t = truth.reshape(-1) - truth.mean()
    e = estimate.reshape(-1) - estimate.mean()
    norm = torch.linalg.vector_norm(t) * torch.linalg.vector_norm(e)
    if float(norm.detach()) == 0.0:
        return torch.zeros((), dtype=torch.float64, device=truth.device)
    return ((t * e).sum() / norm).clamp(-1.0, 1.0)
