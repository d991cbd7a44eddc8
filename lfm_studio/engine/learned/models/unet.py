"""The blind U-Net: no physics (the reference of thesis section 4.2.1).

The camera image is area-resampled onto the volume's lateral grid and a small 2-D U-Net maps
it to one channel per depth (softplus: non-negative). It sees the light field only as an
image, so whatever it learns about the optics comes from the training pairs.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import torch
import torch.nn.functional as nnf
from torch import nn

from lfm_studio.engine.learned.models.common import SmallUNet, image_scale, projector_dtype
from lfm_studio.engine.operators.protocol import Projector


class BlindUNet(nn.Module):
    """Image ``(Py, Px)`` -> volume ``(Z, Vy, Vx)`` with a U-Net of ``width`` features; no projector calls."""

    def __init__(self, projector: Projector, *, width: int = 16) -> None:
        super().__init__()
        self.volume_shape = tuple(projector.volume_shape)
        self.config = {"width": width}
        self.net = SmallUNet(1, self.volume_shape[0], width)
        self.to(projector_dtype(projector))

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        y = image.to(self.net.head.weight.dtype)
        scale = image_scale(y)
        small = nnf.interpolate((y / scale)[None, None], size=self.volume_shape[1:], mode="area")[0]
        return nnf.softplus(self.net(small)) * scale
