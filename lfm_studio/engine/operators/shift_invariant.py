"""Laterally shift-invariant projector (Fourier LFM): ``y = crop(sum_z x_z * h_z)``.

The volume ``x`` has shape ``(Z, Vy, Vx)`` on the sample-side lateral grid
(voxel = sensor pixel / magnification); each depth is convolved with its PSF
``h_z`` (shape ``(Py, Px)``, the sensor) and the full linear convolution is cropped
to the sensor, centred. The adjoint is the exact transpose: embed the image in the
full convolution window, correlate with each PSF, crop each depth to the volume.

FFT sizes avoid circular wrap-around (``>= V + P - 1``, 2-3-5 smooth); the PSF
spectra (OTFs) are computed once and kept. On CPU, depths are processed in chunks
that keep the working set cache-sized (batching all depths at once was measured
3-4x slower at 1024^2 here, PLATFORM.md); on CUDA all depths go in one batch.
"""

from __future__ import annotations

import torch

from lfm_studio.engine import fft
from lfm_studio.engine.errors import require_finite_tensor
from lfm_studio.engine.operators.fft_sizes import next_fast_length

_CPU_CHUNK_BYTES = 24 * 2**20  # about the 32 MB L3 of this CPU, leaving room for the output


def _centre_offset(full: int, part: int) -> int:
    """Start index of a centred window of length ``part`` inside ``full``."""
    return (full - part + 1) // 2


class ShiftInvariantProjector:
    """``A`` and ``A^T`` for a PSF stack that is laterally shift-invariant.

    Parameters
    ----------
    psf : tensor, shape ``(Z, Py, Px)``
        Non-negative PSF per depth on the sensor grid (the image has this lateral shape).
    lateral_shape : (Vy, Vx)
        Lateral shape of the volumes this projector accepts (sample side, in voxels).
    depth_chunk : int or None
        Depths per FFT batch; ``None`` picks a cache-sized chunk on CPU and all depths on CUDA.

    The projector is differentiable (plain torch ops); dtype follows ``psf``
    (float32 or float64).
    """

    def __init__(
        self, psf: torch.Tensor, lateral_shape: tuple[int, int], *, depth_chunk: int | None = None
    ) -> None:
        if psf.ndim != 3 or psf.is_complex():
            raise ValueError(f"psf must be a real tensor of shape (Z, Py, Px); got shape {tuple(psf.shape)}.")
        require_finite_tensor("psf", psf.detach())
        if bool(psf.detach().sum() <= 0):
            raise ValueError(
                "psf is all zero (or negative): nothing reaches the camera. Fix: check the design."
            )
        vy, vx = (int(v) for v in lateral_shape)
        if vy < 1 or vx < 1:
            raise ValueError(f"lateral_shape must be positive; got {lateral_shape!r}.")
        self.depths, self.psf_shape = psf.shape[0], (psf.shape[1], psf.shape[2])
        self.lateral_shape = (vy, vx)
        self.full_shape = (vy + self.psf_shape[0] - 1, vx + self.psf_shape[1] - 1)
        self.fft_shape = (next_fast_length(self.full_shape[0]), next_fast_length(self.full_shape[1]))
        self.dtype, self.device = psf.dtype, psf.device
        self.depth_chunk = depth_chunk or self._default_chunk()
        padded = torch.zeros((self.depths, *self.fft_shape), dtype=psf.dtype, device=psf.device)
        padded[:, : self.psf_shape[0], : self.psf_shape[1]] = psf
        self.otf = fft.rfft2(padded)  # (Z, Fy, Fx//2+1)

    def _default_chunk(self) -> int:
        if self.device.type != "cpu":
            return self.depths
        spectrum_bytes = (
            self.fft_shape[0] * (self.fft_shape[1] // 2 + 1) * 2 * (4 if self.dtype == torch.float32 else 8)
        )
        return max(1, min(self.depths, _CPU_CHUNK_BYTES // max(1, spectrum_bytes)))

    @property
    def volume_shape(self) -> tuple[int, int, int]:
        """``(Z, Vy, Vx)`` of the volumes :meth:`forward` accepts."""
        return (self.depths, *self.lateral_shape)

    @property
    def image_shape(self) -> tuple[int, int]:
        """Lateral shape of the camera image, ``(Py, Px)``."""
        return self.psf_shape

    def _chunks(self):
        for start in range(0, self.depths, self.depth_chunk):
            yield slice(start, min(self.depths, start + self.depth_chunk))

    def forward(self, volume: torch.Tensor) -> torch.Tensor:
        """``A x``: volume ``(Z, Vy, Vx)`` -> image ``(Py, Px)``."""
        if tuple(volume.shape) != self.volume_shape:
            raise ValueError(
                f"volume must have shape {self.volume_shape} (Z, Vy, Vx); got {tuple(volume.shape)}."
            )
        volume = volume.to(device=self.device, dtype=self.dtype)
        total = None
        for part in self._chunks():
            spectrum = fft.rfft2(self._embed(volume[part], self.lateral_shape))
            term = (spectrum * self.otf[part]).sum(dim=0)
            total = term if total is None else total + term
        full = fft.irfft2(total, s=self.fft_shape)
        oy = _centre_offset(self.full_shape[0], self.psf_shape[0])
        ox = _centre_offset(self.full_shape[1], self.psf_shape[1])
        return full[oy : oy + self.psf_shape[0], ox : ox + self.psf_shape[1]]

    def adjoint(self, image: torch.Tensor) -> torch.Tensor:
        """``A^T y``: image ``(Py, Px)`` -> volume ``(Z, Vy, Vx)`` (exact transpose of :meth:`forward`)."""
        if tuple(image.shape) != self.psf_shape:
            raise ValueError(f"image must have shape {self.psf_shape} (Py, Px); got {tuple(image.shape)}.")
        image = image.to(device=self.device, dtype=self.dtype)
        oy = _centre_offset(self.full_shape[0], self.psf_shape[0])
        ox = _centre_offset(self.full_shape[1], self.psf_shape[1])
        embedded = torch.zeros(self.fft_shape, dtype=self.dtype, device=self.device)
        embedded[oy : oy + self.psf_shape[0], ox : ox + self.psf_shape[1]] = image
        spectrum = fft.rfft2(embedded)
        parts = []
        for part in self._chunks():
            corr = fft.irfft2(spectrum * self.otf[part].conj(), s=self.fft_shape)
            parts.append(corr[:, : self.lateral_shape[0], : self.lateral_shape[1]])
        return torch.cat(parts, dim=0)

    def _embed(self, block: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
        out = torch.zeros((block.shape[0], *self.fft_shape), dtype=self.dtype, device=self.device)
        out[:, : shape[0], : shape[1]] = block
        return out
