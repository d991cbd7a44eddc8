"""The linear-convolution geometry of a shift-invariant projector, for Fourier-domain solvers.

:class:`~lfm_studio.engine.operators.ShiftInvariantProjector` convolves each depth,
zero-padded into an FFT window ``fft_shape`` (at least ``V + P - 1``, so nothing wraps),
with its PSF and crops the full convolution (``full_shape``) to the sensor, centred.
Its adjoint embeds the image at that centred offset, correlates with each PSF and keeps
the top-left ``(Vy, Vx)`` corner. The Wiener, Tikhonov and unmatched back-projection
filters here do exactly the same embedding and cropping with other per-depth filters,
so they act on the same grids as the projector (a test checks that the matched filter
``conj(otf)`` reproduces ``projector.adjoint`` to rounding).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TypeAlias

import torch

from lfm_studio.engine import fft
from lfm_studio.engine.operators.protocol import FourierProjector, missing_members
from lfm_studio.engine.types import DepthSlice, Shape2

#: Per-depth filters: a ``(Z, Fy, Fx//2+1)`` tensor, or ``slice -> filters[slice]`` built on demand.
Filters: TypeAlias = torch.Tensor | Callable[[DepthSlice], torch.Tensor]


def require_fourier_projector(projector: object, method: str) -> FourierProjector:
    """``projector`` as a :class:`FourierProjector`; ``NotImplementedError`` naming what it lacks if not."""
    if not isinstance(projector, FourierProjector):
        raise NotImplementedError(
            f"{method} needs a laterally shift-invariant projector with cached OTFs (Fourier LFM, "
            f"ShiftInvariantProjector); {type(projector).__name__} has no "
            f"{', '.join(missing_members(projector, FourierProjector))}. "
            "Fix: use Richardson-Lucy (plain or Biggs-Andrews accelerated), which works with any projector, or "
            "tikhonov, which also solves a lenslet-lattice (conventional LFM) projector in closed form."
        )
    return projector


def centre_offsets(projector: FourierProjector) -> Shape2:
    """Start of the sensor window inside the full convolution (as the projector crops it)."""
    (fy, fx), (py, px) = projector.full_shape, projector.image_shape
    return (fy - py + 1) // 2, (fx - px + 1) // 2


def image_spectrum(projector: FourierProjector, image: torch.Tensor) -> torch.Tensor:
    """``rfft2`` of the image embedded in the FFT window at the sensor offset, shape ``(Fy, Fx//2+1)``."""
    oy, ox = centre_offsets(projector)
    py, px = projector.image_shape
    embedded = torch.zeros(projector.fft_shape, dtype=image.dtype, device=image.device)
    embedded[oy : oy + py, ox : ox + px] = image
    return fft.rfft2(embedded)


def volume_spectrum(projector: FourierProjector, volume: torch.Tensor) -> torch.Tensor:
    """``rfft2`` of each depth zero-padded into the FFT window (top-left), shape ``(Z, Fy, Fx//2+1)``."""
    _, vy, vx = projector.volume_shape
    padded = torch.zeros((volume.shape[0], *projector.fft_shape), dtype=volume.dtype, device=volume.device)
    padded[:, :vy, :vx] = volume
    return fft.rfft2(padded)


def depth_chunks(projector: FourierProjector) -> Iterator[DepthSlice]:
    """Depth slices of the projector's cache-sized chunks."""
    return projector.depth_chunks()


def filter_to_volume(projector: FourierProjector, spectrum: torch.Tensor, filters: Filters) -> torch.Tensor:
    """``crop(irfft2(filters[z] * spectrum))`` per depth -> volume ``(Z, Vy, Vx)``.

    ``filters`` is a ``(Z, Fy, Fx//2+1)`` complex tensor or a callable ``slice -> filters[slice]``
    (so large filters can be formed one chunk at a time).
    """
    _, vy, vx = projector.volume_shape
    parts = []
    for part in depth_chunks(projector):
        block = filters[part] if isinstance(filters, torch.Tensor) else filters(part)
        full = fft.irfft2(block * spectrum, s=projector.fft_shape)
        parts.append(full[:, :vy, :vx])
    return torch.cat(parts, dim=0)


def spectra_to_volume(projector: FourierProjector, spectra: torch.Tensor) -> torch.Tensor:
    """``crop(irfft2(spectra))`` for per-depth spectra ``(Z, Fy, Fx//2+1)`` -> ``(Z, Vy, Vx)``."""
    _, vy, vx = projector.volume_shape
    return fft.irfft2(spectra, s=projector.fft_shape)[:, :vy, :vx]


def radial_frequency(projector: FourierProjector) -> torch.Tensor:
    """``|k|`` in cycles per sensor pixel on the rfft grid, shape ``(Fy, Fx//2+1)``, float64."""
    fy, fx = projector.fft_shape
    ky = torch.fft.fftfreq(fy, dtype=torch.float64, device=projector.otf.device)
    kx = torch.fft.rfftfreq(fx, dtype=torch.float64, device=projector.otf.device)
    return torch.sqrt(ky[:, None] ** 2 + kx[None, :] ** 2)


def otf_peaks(projector: FourierProjector) -> torch.Tensor:
    """Largest ``|otf|`` per depth, shape ``(Z,)`` (the DC gain = PSF sum for a non-negative PSF)."""
    return projector.otf.abs().flatten(1).amax(dim=1)
