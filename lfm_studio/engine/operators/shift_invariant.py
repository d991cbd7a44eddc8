"""Laterally shift-invariant projector (Fourier LFM): ``y = crop(sum_z x_z * h_z)``.

The volume ``x`` has shape ``(Z, Vy, Vx)`` on the sample-side lateral grid
(voxel = sensor pixel / magnification); each depth is convolved with its PSF
``h_z`` (shape ``(Py, Px)``, the sensor) and the full linear convolution is cropped
to the sensor, centred. The adjoint is the exact transpose: embed the image in the
full convolution window, correlate with each PSF, crop each depth to the volume.

FFT sizes avoid circular wrap-around (``>= V + P - 1``, 2-3-5 smooth); the PSF
spectra (OTFs) are computed once and kept (in the same depth chunks, so the set-up
is linear in depths). On CPU, depths are processed in chunks
that keep the working set cache-sized (batching all depths at once was measured
3-4x slower at 1024^2 here, docs/platform.md); on CUDA all depths go in one batch.

Without autograd (RL, Landweber: nothing requires grad) the forward zeroes one column window
per call and the back projection reuses one product buffer; with autograd every step is a pure
torch function (differentiable in the volume, the image and the PSF). The two agree to float
rounding (``tests/engine/operators/test_shift_invariant.py``). Every transform is torch's
(:mod:`lfm_studio.engine.fft`): one FFT implementation, whatever else is installed.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch

from lfm_studio.engine import fft
from lfm_studio.engine.errors import as_real_tensor, require_finite_tensor
from lfm_studio.engine.operators.fft_sizes import next_fast_length
from lfm_studio.engine.types import DepthSlice, TensorLike

_CPU_CHUNK_BYTES = 24 * 2**20  # about the 32 MB L3 of this CPU, leaving room for the output


def _centre_offset(full: int, part: int) -> int:
    """Start index of a centred window of length ``part`` inside ``full``."""
    return (full - part + 1) // 2


def _zero_padded(rows: torch.Tensor, length: int) -> torch.Tensor:
    """``rows`` zero-padded at the end of the last dim to ``length`` (contiguous).

    Padding by hand before an FFT of exactly ``length``: where freed memory goes back to
    the system (no :func:`lfm_studio.engine.allocator.keep_freed_memory`), torch's own
    ``n=length`` path took 83-244 ms for a 1201 x 339 complex64 block to 2400 points
    against 38 ms padded first (1 thread); with kept memory both take the same time.
    """
    return torch.nn.functional.pad(rows, (0, length - rows.shape[-1]))


def _tracked(*tensors: torch.Tensor) -> bool:
    """Whether autograd records operations on any of ``tensors`` (then no in-place buffer reuse)."""
    return torch.is_grad_enabled() and any(t.requires_grad for t in tensors)


def _multiply_accumulate(total: torch.Tensor, spectra: torch.Tensor, otf: torch.Tensor) -> torch.Tensor:
    """``total + sum_i spectra[i] * otf[i]``, one fused pass per depth (no ``(c, Kx, Fy)`` product
    temporary); in place unless autograd tracks the values."""
    for i in range(spectra.shape[0]):
        if total.requires_grad or spectra.requires_grad or otf.requires_grad:
            total = total.addcmul(spectra[i], otf[i])
        else:
            total.addcmul_(spectra[i], otf[i])
    return total


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
        self.otf_t = self._spectra(psf)

    def _spectra(self, psf: torch.Tensor) -> torch.Tensor:
        """OTFs in the transposed layout ``(Z, Fx//2+1, Fy)``: every 1D pass runs along contiguous memory.

        Computed chunk by chunk of depths (as :meth:`forward` runs), so the set-up's working
        set stays cache-sized and its time grows linearly with the number of depths; only
        the result is allocated whole. Differentiable with respect to ``psf``.
        """
        fy, fx = self.fft_shape
        otf_t = None
        for part in self.depth_chunks():
            rows = fft.rfft_along(psf[part], fx, dim=-1).transpose(-2, -1)  # (c, Kx, Py), a view
            spectra = fft.fft_along(_zero_padded(rows, fy), fy, dim=-1)  # (c, Kx, Fy)
            if otf_t is None:
                otf_t = spectra.new_empty((self.depths, *spectra.shape[1:]))
            otf_t[part] = spectra
        assert otf_t is not None  # at least one depth
        return otf_t

    @property
    def otf(self) -> torch.Tensor:
        """PSF spectra ``(Z, Fy, Fx//2+1)`` of the zero-padded PSFs (the ``rfft2`` layout; a view)."""
        return self.otf_t.transpose(-2, -1)

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

    def depth_chunks(self) -> Iterator[DepthSlice]:
        """Depth slices of ``depth_chunk`` depths (the last one may be shorter), in order."""
        for start in range(0, self.depths, self.depth_chunk):
            yield slice(start, min(self.depths, start + self.depth_chunk))

    def forward(self, volume: TensorLike) -> torch.Tensor:
        """``A x``: volume ``(Z, Vy, Vx)`` (a tensor or an array, taken in the projector's dtype and
        device) -> image ``(Py, Px)``.

        Pruned transforms: a slice fills only ``Vy`` of the ``Fy`` window rows, so the row
        ``rfft`` runs on those rows; the inverse column transform is cropped to the sensor
        rows before the last ``irfft``.
        """
        volume = as_real_tensor("volume", volume, dtype=self.dtype, device=self.device)
        if tuple(volume.shape) != self.volume_shape:
            raise ValueError(
                f"volume must have shape {self.volume_shape} (Z, Vy, Vx); got {tuple(volume.shape)}."
            )
        fy, fx = self.fft_shape
        tracked = _tracked(volume, self.otf_t)
        total, window = None, None
        for part in self.depth_chunks():
            rows = fft.rfft_along(volume[part], fx, dim=-1).transpose(-2, -1)  # (c, Kx, Vy), a view
            if tracked:
                spectra = fft.fft_along(_zero_padded(rows, fy), fy, dim=-1)  # (c, Kx, Fy)
            else:  # one zeroed window per call; each chunk only overwrites its Vy rows (no pad pass)
                if window is None:
                    window = rows.new_zeros((self.depth_chunk, rows.shape[1], fy))
                block = window[: rows.shape[0]]
                block[..., : rows.shape[-1]].copy_(rows)
                spectra = fft.column_fft(block)
            if total is None:
                total = spectra.new_zeros(spectra.shape[1:])
            total = _multiply_accumulate(total, spectra, self.otf_t[part])
        assert total is not None  # at least one depth
        oy = _centre_offset(self.full_shape[0], self.psf_shape[0])
        ox = _centre_offset(self.full_shape[1], self.psf_shape[1])
        columns = fft.column_ifft_unscaled(total)[:, oy : oy + self.psf_shape[0]]  # (Kx, Py)
        image = fft.irfft_along_unscaled(columns.transpose(0, 1).contiguous(), fx, dim=-1)
        return image[:, ox : ox + self.psf_shape[1]] * (1.0 / (fy * fx))

    def adjoint(self, image: TensorLike) -> torch.Tensor:
        """``A^T y``: image ``(Py, Px)`` (tensor or array) -> volume ``(Z, Vy, Vx)`` (exact transpose of
        :meth:`forward`)."""
        return self.filtered_adjoint(image, self.otf_t.conj())

    def filtered_adjoint(self, image: TensorLike, filters_t: torch.Tensor) -> torch.Tensor:
        """``crop(irfft2(filters_z * rfft2(embed(y))))`` per depth: image ``(Py, Px)`` -> ``(Z, Vy, Vx)``.

        ``filters_t`` are per-depth spectra in the transposed layout of :attr:`otf_t`,
        ``(Z, Fx//2+1, Fy)``; ``conj(otf_t)`` gives :meth:`adjoint`, other filters give
        unmatched back projectors (Wiener-Butterworth) at the same cost (pruned transforms).
        """
        image = as_real_tensor("image", image, dtype=self.dtype, device=self.device)
        if tuple(image.shape) != self.psf_shape:
            raise ValueError(f"image must have shape {self.psf_shape} (Py, Px); got {tuple(image.shape)}.")
        if tuple(filters_t.shape) != tuple(self.otf_t.shape):
            raise ValueError(
                f"filters_t must have the shape of otf_t {tuple(self.otf_t.shape)} (Z, Fx//2+1, Fy); "
                f"got {tuple(filters_t.shape)}."
            )
        fy, fx = self.fft_shape
        (py, px), (vy, vx) = self.psf_shape, self.lateral_shape
        oy = _centre_offset(self.full_shape[0], py)
        ox = _centre_offset(self.full_shape[1], px)
        rows = fft.rfft_along(torch.nn.functional.pad(image, (ox, fx - ox - px)), fx, dim=-1)  # (Py, Kx)
        rows = torch.nn.functional.pad(rows.transpose(0, 1), (oy, fy - oy - py))  # (Kx, Fy), image rows at oy
        spectrum = fft.column_fft(rows)
        # ifft(S H*) = conj(fft(conj(S) H)): with the adjoint's conj(otf) filters every depth then
        # multiplies plain tensors (a product with a lazily conjugated operand runs ~1.7x slower
        # here) and only the cropped (Kx, Vy) columns are conjugated.
        flipped = filters_t.is_conj()
        if flipped:
            spectrum, filters_t = spectrum.conj().resolve_conj(), filters_t.conj()
        scale = 1.0 / (fy * fx)
        out, parts = spectrum.real.new_empty(self.volume_shape), []
        tracked = _tracked(spectrum, filters_t)
        buffer = None
        for part in self.depth_chunks():
            if tracked:
                product = spectrum * filters_t[part]  # (c, Kx, Fy)
            else:  # one product buffer per call, reused by every chunk (the last may be shorter)
                if buffer is None:
                    buffer = spectrum.new_empty((self.depth_chunk, *spectrum.shape))
                product = torch.mul(spectrum, filters_t[part], out=buffer[: part.stop - part.start])
            if flipped:
                columns = fft.column_fft(product)[..., :vy].conj()  # (c, Kx, Vy)
            else:
                columns = fft.column_ifft_unscaled(product)[..., :vy]
            rows_t = columns.transpose(-2, -1)  # (c, Vy, Kx), a (lazily conjugated) view
            if tracked:
                rows_t = rows_t.resolve_conj().contiguous()
            else:  # transposed and conjugated in one copy pass
                rows_t = torch.empty(rows_t.shape, dtype=rows_t.dtype, device=rows_t.device).copy_(rows_t)
            back = fft.irfft_along_unscaled(rows_t, fx, dim=-1)
            if back.requires_grad:  # autograd: no writes into a shared output
                parts.append(back[..., :vx] * scale)
            else:  # scaled straight into the output: no concatenation pass
                torch.mul(back[..., :vx], scale, out=out[part])
        return torch.cat(parts, dim=0) if parts else out
