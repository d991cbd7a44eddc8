"""Pieces the learned models share: the projector's grid, photon-scale normalisation, a small U-Net."""

from __future__ import annotations

import torch
import torch.nn.functional as nnf
from torch import nn

from lfm_studio.engine.operators.protocol import Projector


def projector_dtype(projector: Projector) -> torch.dtype:
    """The real dtype the projector computes in (:attr:`Projector.dtype`)."""
    return projector.dtype


def image_scale(image: torch.Tensor) -> torch.Tensor:
    """The mean photon count of ``image`` (> 0): models work on ``image / scale`` and multiply
    their volume back, so a model answers the same at any photon budget up to noise."""
    return image.mean().clamp_min(torch.finfo(image.dtype).tiny)


def adjoint_normaliser(projector: Projector) -> torch.Tensor:
    """``A^T 1`` clamped away from 0: the sensitivity of each voxel (Richardson-Lucy's denominator)."""
    ones = torch.ones(tuple(projector.image_shape), dtype=projector_dtype(projector))
    with torch.no_grad():
        norm = projector.adjoint(ones)
    return norm.clamp_min(float(norm.max()) * 1e-6)


def differentiable_normaliser(projector: Projector) -> torch.Tensor:
    """:func:`adjoint_normaliser` with gradients to the projector's PSF (end-to-end optics training)."""
    norm = projector.adjoint(torch.ones(tuple(projector.image_shape), dtype=projector_dtype(projector)))
    return torch.maximum(norm, norm.detach().max() * 1e-6)


def check_architecture(model: str, architecture: int, current: int) -> None:
    """Refuse an ``architecture`` number other than the ``current`` one of ``model`` (a ValueError naming both)."""
    if architecture != current:
        raise ValueError(
            f"a {model!r} model of architecture {architecture!r} cannot be built by this version of lfm_studio "
            f"(it builds architecture {current}). Fix: train a new model (`lfm-studio train --model {model}`)."
        )


class _DoubleConv(nn.Sequential):
    def __init__(self, inputs: int, outputs: int) -> None:
        super().__init__(
            nn.Conv2d(inputs, outputs, 3, padding=1), nn.ReLU(inplace=True),
            nn.Conv2d(outputs, outputs, 3, padding=1), nn.ReLU(inplace=True),
        )  # fmt: skip


class SmallUNet(nn.Module):
    """A two-level 2-D U-Net (``channels`` in, ``outputs`` out, ``width`` features at the top),
    for ``(C, H, W)`` maps of any size (padded to a multiple of 4, cropped back)."""

    def __init__(self, channels: int, outputs: int, width: int = 16) -> None:
        super().__init__()
        self.down1 = _DoubleConv(channels, width)
        self.down2 = _DoubleConv(width, 2 * width)
        self.bottom = _DoubleConv(2 * width, 2 * width)
        self.up2 = _DoubleConv(4 * width, width)
        self.up1 = _DoubleConv(2 * width, width)
        self.head = nn.Conv2d(width, outputs, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        x = nnf.pad(x[None], (0, (-w) % 4, 0, (-h) % 4))
        a = self.down1(x)
        b = self.down2(nnf.max_pool2d(a, 2))
        c = self.bottom(nnf.max_pool2d(b, 2))
        b = self.up2(torch.cat([b, nnf.interpolate(c, size=b.shape[-2:], mode="nearest")], dim=1))
        a = self.up1(torch.cat([a, nnf.interpolate(b, size=a.shape[-2:], mode="nearest")], dim=1))
        return self.head(a)[0, :, :h, :w]
