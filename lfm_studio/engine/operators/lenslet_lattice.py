"""Conventional-LFM projector: per-position convolutions written as one multi-channel conv2d.

A voxel ``S j + p`` (lenslet ``j``, sub-position ``p``) at depth ``z`` adds its pattern
``H[z, p]`` centred on lenslet ``j``; the pattern is periodic in the lattice. Split the
volume by sub-position (``pixel_unshuffle(S)``: channels ``(z, p)`` on the lenslet
lattice) and the rectified image by pixel position inside a lenslet (``Q x Q``
channels): then

    image_q[j] = sum_{z, p} sum_m x_{z,p}[j - m] H[z, p][m Q + q]

is exactly ``conv2d`` with ``(2R+1) x (2R+1)`` kernels over the lattice, and its
adjoint is ``conv_transpose2d`` with the *same* weights: the back-projection patterns
are index flips of the forward ones, never a second simulation. Depths are grouped by
their reach ``R`` so near-focus depths do not pay for the widest kernels.

Volumes are in sample orientation; the microscope inverts the image, so the volume is
rotated by 180 degrees laterally before projecting (and the adjoint rotates back).
"""

from __future__ import annotations

import torch
from torch.nn import functional as nnf

from lfm_studio.engine.errors import as_real_tensor
from lfm_studio.engine.types import TensorLike


class LensletLatticeProjector:
    """``A`` / ``A^T`` of a conventional LFM on ``(Ly, Lx)`` lenslets.

    Parameters
    ----------
    groups : list of ``(depth_indices, patterns)`` with ``patterns`` of shape
        ``(Zg, S, S, H, H)``, ``H = (2R + 1) Q`` for the group's reach ``R``, from
        :func:`conventional_patterns` (canvas centred on the source lenslet).
    depths : number of depths ``Z`` of the volume.
    lenslets : ``(Ly, Lx)``.
    pixels_per_lenslet : ``Q``.
    """

    def __init__(
        self,
        groups: list[tuple[list[int], torch.Tensor]],
        depths: int,
        lenslets: tuple[int, int],
        pixels_per_lenslet: int,
    ) -> None:
        self.depths = depths
        self.lenslets = lenslets
        self.q = pixels_per_lenslet
        self.s = groups[0][1].shape[1]
        self.dtype, self.device = groups[0][1].dtype, groups[0][1].device
        covered = sorted(i for indices, _ in groups for i in indices)
        if covered != list(range(depths)):
            raise ValueError(f"pattern groups must cover depths 0..{depths - 1} once each; got {covered}.")
        self.groups = [(torch.tensor(idx, device=self.device), self._weights(p)) for idx, p in groups]

    def _weights(self, patterns: torch.Tensor) -> torch.Tensor:
        """Conv weights ``(Q^2, Zg S^2, 2R+1, 2R+1)`` from patterns ``(Zg, S, S, H, H)``."""
        zg, s, _, h, _ = patterns.shape
        q = self.q
        if h % q or (h // q) % 2 == 0:
            raise ValueError(f"pattern size {h} must be an odd multiple of pixels_per_lenslet {q}.")
        k = h // q  # 2R + 1
        # H[m Q + q] with m the lenslet offset: (Zg, S, S, k, Q, k, Q), then flip m for conv2d's correlation.
        blocks = patterns.reshape(zg, s, s, k, q, k, q).flip(3, 5)
        return blocks.permute(4, 6, 0, 1, 2, 3, 5).reshape(q * q, zg * s * s, k, k).contiguous()

    @property
    def volume_shape(self) -> tuple[int, int, int]:
        """``(Z, Ly S, Lx S)``."""
        return (self.depths, self.lenslets[0] * self.s, self.lenslets[1] * self.s)

    @property
    def image_shape(self) -> tuple[int, int]:
        """``(Ly Q, Lx Q)`` rectified pixels."""
        return (self.lenslets[0] * self.q, self.lenslets[1] * self.q)

    def forward(self, volume: TensorLike) -> torch.Tensor:
        """``A x``: volume ``(Z, Ly S, Lx S)`` (tensor or array) -> rectified image ``(Ly Q, Lx Q)``."""
        volume = as_real_tensor("volume", volume, dtype=self.dtype, device=self.device)
        if tuple(volume.shape) != self.volume_shape:
            raise ValueError(
                f"volume must have shape {self.volume_shape} (Z, Ly*S, Lx*S); got {tuple(volume.shape)}."
            )
        x = nnf.pixel_unshuffle(volume.flip(-2, -1)[None], self.s)[0]
        x = x.reshape(self.depths, self.s * self.s, *self.lenslets)
        out = None
        for indices, weight in self.groups:
            channels = x[indices].reshape(1, -1, *self.lenslets)
            term = nnf.conv2d(channels, weight, padding=weight.shape[-1] // 2)
            out = term if out is None else out + term
        assert out is not None  # the groups cover every depth (checked in __init__)
        return nnf.pixel_shuffle(out, self.q)[0, 0]

    def adjoint(self, image: TensorLike) -> torch.Tensor:
        """``A^T y``: rectified image ``(Ly Q, Lx Q)`` (tensor or array) -> volume ``(Z, Ly S, Lx S)``."""
        image = as_real_tensor("image", image, dtype=self.dtype, device=self.device)
        if tuple(image.shape) != self.image_shape:
            raise ValueError(f"image must have shape {self.image_shape}; got {tuple(image.shape)}.")
        y = nnf.pixel_unshuffle(image[None, None], self.q)
        volume = torch.zeros(
            (self.depths, self.s * self.s, *self.lenslets), dtype=self.dtype, device=self.device
        )
        for indices, weight in self.groups:
            back = nnf.conv_transpose2d(y, weight, padding=weight.shape[-1] // 2)
            volume = volume.index_copy(
                0, indices, back.reshape(len(indices), self.s * self.s, *self.lenslets)
            )
        return nnf.pixel_shuffle(volume, self.s)[:, 0].flip(-2, -1)
