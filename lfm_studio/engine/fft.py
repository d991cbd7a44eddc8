"""The engine's only FFT entry point, correct on every CPU we run on.

torch 2.13.0+cpu (MKL) with 2 threads returns a wrong scale (an extra 1/N^2) for
2048 x 2048 complex64 transforms in every *scaled* direction (``ifft2`` with the
default norm, ``fft2`` with ``norm="forward"`` or ``"ortho"``), batched or not;
the *unscaled* directions are right (docs/platform.md; ``tests/engine/test_fft.py``).
So this module only ever asks torch for unscaled transforms and applies the
``1/N`` itself. Everything else in the engine calls these functions, never
``torch.fft`` directly.

Conventions match numpy: ``ifft2(fft2(x)) == x``; the ``centered_*`` variants
treat index ``N // 2`` as the origin in both domains (see ``Grid``).
"""

from __future__ import annotations

import torch

_DIMS = (-2, -1)


def _count(x: torch.Tensor, s: tuple[int, int] | None = None) -> int:
    ny, nx = s if s is not None else x.shape[-2:]
    return int(ny) * int(nx)


def fft2(x: torch.Tensor) -> torch.Tensor:
    """Unnormalised 2D DFT over the last two dims (numpy's ``fft2``)."""
    return torch.fft.fft2(x, dim=_DIMS, norm="backward")


def ifft2(x: torch.Tensor) -> torch.Tensor:
    """Inverse 2D DFT over the last two dims with the ``1/N`` scale (numpy's ``ifft2``)."""
    return torch.fft.ifft2(x, dim=_DIMS, norm="forward") * (1.0 / _count(x))


def rfft2(x: torch.Tensor) -> torch.Tensor:
    """Unnormalised real-input 2D DFT over the last two dims (half spectrum in x)."""
    return torch.fft.rfft2(x, dim=_DIMS, norm="backward")


def irfft2(x: torch.Tensor, s: tuple[int, int]) -> torch.Tensor:
    """Inverse of :func:`rfft2` for a real signal of shape ``s = (ny, nx)``."""
    return torch.fft.irfft2(x, s=s, dim=_DIMS, norm="forward") * (1.0 / _count(x, s))


def centered_fft2(x: torch.Tensor) -> torch.Tensor:
    """2D DFT with the origin at index ``N // 2`` in both domains, unnormalised."""
    return torch.fft.fftshift(fft2(torch.fft.ifftshift(x, dim=_DIMS)), dim=_DIMS)


def centered_ifft2(x: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`centered_fft2` (includes the ``1/N`` scale)."""
    return torch.fft.fftshift(ifft2(torch.fft.ifftshift(x, dim=_DIMS)), dim=_DIMS)


def rfft_along(x: torch.Tensor, n: int, dim: int) -> torch.Tensor:
    """Unnormalised real-input 1D DFT of length ``n`` (zero-padded) along ``dim``."""
    return torch.fft.rfft(x, n=n, dim=dim, norm="backward")


def fft_along(x: torch.Tensor, n: int, dim: int) -> torch.Tensor:
    """Unnormalised complex 1D DFT of length ``n`` (zero-padded) along ``dim``."""
    return torch.fft.fft(x, n=n, dim=dim, norm="backward")


def ifft_along_unscaled(x: torch.Tensor, dim: int) -> torch.Tensor:
    """Inverse 1D DFT along ``dim`` *without* the ``1/n`` (the caller applies the scale once)."""
    return torch.fft.ifft(x, dim=dim, norm="forward")


def irfft_along_unscaled(x: torch.Tensor, n: int, dim: int) -> torch.Tensor:
    """Inverse of :func:`rfft_along` (real output of length ``n``) *without* the ``1/n``."""
    return torch.fft.irfft(x, n=n, dim=dim, norm="forward")


def column_fft(x: torch.Tensor) -> torch.Tensor:
    """:func:`fft_along` the last dim of a complex tensor (the projector's column transforms).

    One implementation on purpose: a scipy (pocketfft) stand-in for untracked CPU tensors measured
    1.4x faster per column block here, but it would be a second FFT path whose results depend on
    what is installed (docs/benchmarks.md, issue 17); torch's is the only one.
    """
    return fft_along(x, x.shape[-1], dim=-1)


def column_ifft_unscaled(x: torch.Tensor) -> torch.Tensor:
    """:func:`ifft_along_unscaled` along the last dim (as :func:`column_fft`)."""
    return ifft_along_unscaled(x, dim=-1)
