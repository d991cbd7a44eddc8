"""MultiWienerNet (Yanny et al. 2022, the thesis' learned model): learnable Wiener filters per
depth initialised from the PSFs, then a small U-Net across depths.

Shift-invariant (Fourier LFM) projector: depth ``z`` is ``F^-1[g_z(|k|) conj(H_z) Y / (|H_z|^2 +
M_z^2 / SNR_z)]`` on the projector's FFT window (as :func:`~lfm_studio.engine.reconstruct.wiener`),
with a learnable ``SNR_z`` (started at ``snr``) and a learnable radial gain ``g_z`` (``bins``
control points from DC to the highest frequency, linear in between, started at 1): an untrained
stage is exactly the Wiener filter. Spatially varying (conventional) projector: the stage is the
normalised adjoint ``A^T y / A^T 1`` with a learnable gain per depth (started at 1). A 2.5-D U-Net (depths as
channels) then refines the stack; its output is added to the stage's and passed through a
softplus (non-negative).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as nnf
from torch import nn

from lfm_studio.engine.learned.models.common import (
    SmallUNet,
    adjoint_normaliser,
    image_scale,
    projector_dtype,
)
from lfm_studio.engine.operators.protocol import FourierProjector, Projector
from lfm_studio.engine.reconstruct.fourier_geometry import (
    filter_to_volume,
    image_spectrum,
    otf_peaks,
    radial_frequency,
    require_fourier_projector,
)
from lfm_studio.engine.types import DepthSlice


class MultiWienerNet(nn.Module):
    """Learnable per-depth Wiener filters (or normalised adjoint) + a U-Net of ``width`` features."""

    def __init__(self, projector: Projector, *, snr: float = 100.0, bins: int = 8, width: int = 16) -> None:
        super().__init__()
        self.projector = projector
        depths = int(projector.volume_shape[0])
        self.config = {"snr": snr, "bins": bins, "width": width}
        self.fourier = isinstance(projector, FourierProjector)
        if self.fourier:
            self.log_snr = nn.Parameter(torch.full((depths,), math.log(snr)))
            self.radial_gain = nn.Parameter(torch.ones(depths, bins))
        else:
            self.depth_gain = nn.Parameter(torch.ones(depths))
            self.norm: torch.Tensor
            self.register_buffer("norm", adjoint_normaliser(projector), persistent=False)
        self.net = SmallUNet(depths, depths, width)
        self.to(projector_dtype(projector))

    def _wiener(self, y: torch.Tensor) -> torch.Tensor:
        projector = require_fourier_projector(self.projector, "MultiWienerNet's Wiener stage")
        otf = projector.otf
        peaks2 = otf_peaks(projector).to(y.dtype) ** 2
        frequency = radial_frequency(projector).to(y.dtype)
        position = frequency / frequency.max() * (self.radial_gain.shape[1] - 1)
        low = position.floor().long().clamp(max=self.radial_gain.shape[1] - 2)
        weight = position - low

        def filters(part: DepthSlice) -> torch.Tensor:
            h = otf[part]
            gain = self.radial_gain[part]
            radial = gain[:, low] * (1 - weight) + gain[:, low + 1] * weight
            regulariser = (peaks2[part] / torch.exp(self.log_snr[part]))[:, None, None]
            return h.conj() * (radial / (h.real**2 + h.imag**2 + regulariser))

        return filter_to_volume(projector, image_spectrum(projector, y), filters)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        y = image.to(self.net.head.weight.dtype)
        scale = image_scale(y)
        y = y / scale
        if self.fourier:
            stage = self._wiener(y)
        else:
            stage = self.projector.adjoint(y) / self.norm * self.depth_gain[:, None, None]
        return nnf.softplus(stage + self.net(stage)) * scale
