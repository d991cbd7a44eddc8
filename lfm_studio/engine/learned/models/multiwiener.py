"""MultiWienerNet (Yanny et al. 2022, the thesis' learned model): learnable Wiener filters per
depth initialised from the PSFs, then a small U-Net across depths.

Shift-invariant (Fourier LFM) projector: depth ``z`` is ``F^-1[g_z(|k|) conj(H_z) Y / (|H_z|^2 +
M_z^2 / SNR_z)]`` on the projector's FFT window (as :func:`~lfm_studio.engine.reconstruct.wiener`),
with an ``SNR_z`` (started at ``snr``, dimensionless) and a radial gain ``g_z`` (``bins``
control points from DC to the highest frequency, linear in between, started at 1): an untrained
stage is exactly the Wiener filter. The stage costs one adjoint ``A^T`` (the projector's pruned
transforms, :mod:`.wiener_stage`); without autograd its filters are built once per parameter state
and kept, so inference is that adjoint plus the U-Net. By default (``learn_filters=False``)
``SNR_z`` and ``g_z`` stay at their start (not trained, not counted as parameters): a training step
then has no gradient through the FFTs, only through the U-Net, and runs about 3x faster at
512^2 x 32 depths (docs/learned.md); ``learn_filters=True`` trains them too (MultiWienerNet
proper).

Conventional-LFM projector (periodic in the lenslet lattice, not shift-invariant): the stage is
the closed-form Tikhonov solution per lattice frequency
(:class:`~lfm_studio.engine.operators.lattice_spectra.LatticeTikhonov`, ``mu = 1 / snr``, built
once per projector and fixed) with a learnable gain per depth (started at 1): the multi-depth
analogue of the Wiener filters for a spatially varying, lattice-periodic system (architecture 3;
architecture 2 used the normalised adjoint ``A^T y / A^T 1`` there, 6x less correlated with the
truth on the benchmark's conventional preset). Any other projector still gets that normalised
adjoint.

A 2.5-D U-Net (depths as channels) then refines the stage divided by its largest magnitude (so it
sees values of order 1 at any photon budget and sampling); its output is added to that stage,
passed through a sharp softplus (non-negative, :data:`SHARPNESS`), multiplied back and by a
learnable gain ``exp(log_gain)`` (started at 1). The output is in photons per voxel and
proportional to the image.

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
    check_architecture,
    image_scale,
    projector_dtype,
)
from lfm_studio.engine.learned.models.wiener_stage import WienerGeometry, check_bins
from lfm_studio.engine.operators.lattice_spectra import LatticeTikhonov, lattice_tikhonov
from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.operators.protocol import FourierProjector, Projector
from lfm_studio.engine.reconstruct.fourier_geometry import require_fourier_projector

SHARPNESS = 50.0
"""``beta`` of the output softplus, on the stage divided by its peak: 0 maps to ``log(2) / 50``, 1.4 %
of the peak (a plain softplus put 69 % of the peak on every empty voxel, and training collapsed)."""


WIENER_SNR = 100.0
"""Default ``snr`` of the Wiener stage per depth (shift-invariant projector)."""
LATTICE_SNR = 1000.0
"""Default ``snr`` of the Tikhonov stage per lattice frequency (lenslet-lattice projector; the
registry's Tikhonov default)."""


class MultiWienerNet(nn.Module):
    """Learnable per-depth Wiener filters (or lattice Tikhonov, or normalised adjoint) + a U-Net of ``width`` features."""

    ARCHITECTURE = 3
    """Checkpoints of another architecture are refused (1: the U-Net saw the stage in photons
    divided by the image's mean, without the output gain; 2: the conventional stage was the
    normalised adjoint, so architecture 2 is still built for every other projector: :meth:`builds`)."""

    @classmethod
    def builds(cls, architecture: object, projector: Projector) -> bool:
        """Whether this version builds ``architecture`` on ``projector`` (2 and 3 agree off the lenslet lattice)."""
        if isinstance(architecture, bool) or not isinstance(architecture, int):
            return False
        return architecture == cls.ARCHITECTURE or (
            architecture == 2 and not isinstance(projector, LensletLatticeProjector)
        )

    def __init__(
        self,
        projector: Projector,
        *,
        snr: float | None = None,
        bins: int = 8,
        width: int = 16,
        learn_filters: bool = False,
        architecture: int = ARCHITECTURE,
    ) -> None:
        super().__init__()
        if not self.builds(architecture, projector):
            check_architecture("multiwiener", architecture, self.ARCHITECTURE)
        self.projector = projector
        depths = int(projector.volume_shape[0])
        lattice = projector if isinstance(projector, LensletLatticeProjector) else None
        if snr is None:
            snr = LATTICE_SNR if lattice is not None else WIENER_SNR
        if learn_filters and not isinstance(projector, FourierProjector):
            raise ValueError(
                f"learn_filters=True needs a shift-invariant (Fourier LFM) projector; got a "
                f"{type(projector).__name__}, whose stage is fixed (the lattice Tikhonov operator costs a solve "
                "per lattice frequency to rebuild). Fix: leave learn_filters false; the per-depth gain is learnt."
            )
        self.config = {"snr": snr, "bins": bins, "width": width, "learn_filters": learn_filters,
                       "architecture": architecture}  # fmt: skip
        self.fourier = isinstance(projector, FourierProjector)
        self.lattice: LatticeTikhonov | None = None
        self._cached: tuple[object, torch.Tensor] | None = None
        if isinstance(projector, FourierProjector):
            self.geometry = WienerGeometry(projector, check_bins(bins))
            self.log_snr = nn.Parameter(torch.full((depths,), math.log(snr)))
            self.radial_gain = nn.Parameter(torch.ones(depths, bins))
            self.log_snr.requires_grad_(learn_filters)
            self.radial_gain.requires_grad_(learn_filters)
        else:
            self.depth_gain = nn.Parameter(torch.ones(depths))
            if lattice is not None:  # architecture 3 (builds() refused another one on the lattice)
                self.lattice = lattice_tikhonov(lattice, 1.0 / float(snr))
            else:
                self.norm: torch.Tensor
                self.register_buffer("norm", adjoint_normaliser(projector), persistent=False)
        self.net = SmallUNet(depths, depths, width)
        self.log_gain = nn.Parameter(torch.zeros(()))
        self.to(projector_dtype(projector))

    def _wiener(self, y: torch.Tensor) -> torch.Tensor:
        """The Wiener stage of image ``y`` ``(Py, Px)``: volume ``(Z, Vy, Vx)`` (:mod:`.wiener_stage`)."""
        require_fourier_projector(self.projector, "MultiWienerNet's Wiener stage")
        return self.geometry.apply(y, self._filters())

    def _filters(self) -> torch.Tensor:
        """The stage's filters; without autograd, built once per parameter state and kept.

        The key is each parameter's storage and in-place version counter, so an optimiser step,
        ``load_state_dict`` or a dtype/device move builds them again.
        """
        if torch.is_grad_enabled() and (self.log_snr.requires_grad or self.radial_gain.requires_grad):
            return self.geometry.filters(self.log_snr, self.radial_gain)
        key = tuple((p.data_ptr(), p._version, p.dtype) for p in (self.log_snr, self.radial_gain))
        if self._cached is None or self._cached[0] != key:
            with torch.no_grad():
                self._cached = (key, self.geometry.filters(self.log_snr, self.radial_gain))
        return self._cached[1]

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        y = image.to(self.net.head.weight.dtype)
        scale = image_scale(y)
        y = y / scale
        if self.fourier:
            stage = self._wiener(y)
        elif self.lattice is not None:
            stage = self.lattice(y) * self.depth_gain[:, None, None]
        else:
            stage = self.projector.adjoint(y) / self.norm * self.depth_gain[:, None, None]
        level = stage.detach().abs().amax().clamp_min(torch.finfo(stage.dtype).tiny)
        unit = stage / level  # the U-Net sees the stage at its own scale: peak magnitude 1
        gain = torch.exp(self.log_gain)
        return nnf.softplus(unit + self.net(unit), beta=SHARPNESS) * (level * gain * scale)
