"""A projector onto a camera whose pixels are ``k x k`` blocks of a finer projector's image.

Used for a Fourier-LFM volume finer than sensor pixel / magnification
(``accuracy.volume_oversampling`` ``k``): the PSF is sampled on a virtual sensor with
pixels ``k`` times smaller, the inner projector maps the fine volume onto that virtual
sensor, and each camera pixel receives the sum of its ``k x k`` virtual pixels (the
power on a pixel is the integral over its area, which is additive, so this is exact).
The adjoint spreads each camera pixel back onto its block: the exact transpose.

Blocks are ``[k i, k i + k)`` of the fine image; fine rows/columns beyond ``k Py`` / ``k
Px`` are dropped (:func:`~lfm_studio.engine.systems.from_design.fourier_system_of` adds
``k - 1`` of them on an even axis so that each block is centred like its camera pixel).
"""

from __future__ import annotations

import torch

from lfm_studio.engine.errors import as_real_tensor
from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.types import Shape2, Shape3, TensorLike


class BinnedProjector:
    """``A = B A_fine``: ``A_fine`` (any :class:`Projector`) then ``k x k`` sums.

    Parameters
    ----------
    inner : Projector
        The fine projector (at least ``factor`` pixels per axis); the camera has
        ``image_shape // factor`` pixels. Dtype and device are the inner projector's.
    factor : int
        Virtual pixels per camera pixel along each axis (>= 1).
    """

    def __init__(self, inner: Projector, factor: int) -> None:
        if not (isinstance(factor, int) and factor >= 1):
            raise ValueError(f"factor must be an integer >= 1 (virtual pixels per pixel); got {factor!r}.")
        py, px = inner.image_shape
        if py < factor or px < factor:
            raise ValueError(f"the inner image {(py, px)} is smaller than one block of {factor} x {factor}.")
        self.inner, self.factor = inner, factor

    @property
    def dtype(self) -> torch.dtype:
        """The inner projector's dtype."""
        return self.inner.dtype

    @property
    def device(self) -> torch.device:
        """The inner projector's device."""
        return self.inner.device

    @property
    def volume_shape(self) -> Shape3:
        """``(Z, Vy, Vx)`` of the (fine) volumes :meth:`forward` accepts."""
        return self.inner.volume_shape

    @property
    def image_shape(self) -> Shape2:
        """Lateral shape of the camera image."""
        py, px = self.inner.image_shape
        return (py // self.factor, px // self.factor)

    def forward(self, volume: TensorLike) -> torch.Tensor:
        """``A x``: volume (tensor or array) -> camera image (sums of ``k x k`` virtual pixels)."""
        fine = self.inner.forward(as_real_tensor("volume", volume, dtype=self.dtype, device=self.device))
        k, (py, px) = self.factor, self.image_shape
        return fine[: k * py, : k * px].reshape(py, k, px, k).sum(dim=(1, 3))

    def adjoint(self, image: TensorLike) -> torch.Tensor:
        """``A^T y``: each camera pixel of ``image`` (tensor or array) copied onto its ``k x k`` block,
        then the inner adjoint."""
        image = as_real_tensor("image", image, dtype=self.dtype, device=self.device)
        if tuple(image.shape) != self.image_shape:
            raise ValueError(f"image must have shape {self.image_shape} (Py, Px); got {tuple(image.shape)}.")
        k, (fy, fx) = self.factor, self.inner.image_shape
        spread = image.repeat_interleave(k, dim=0).repeat_interleave(k, dim=1)
        fine = torch.zeros((fy, fx), dtype=spread.dtype, device=spread.device)
        fine[: spread.shape[0], : spread.shape[1]] = spread
        return self.inner.adjoint(fine)
