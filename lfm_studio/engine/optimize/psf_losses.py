"""PSF-engineering objectives of thesis section 5.2.2, differentiable functions of a PSF stack.

Every function takes a real PSF stack ``psf`` of shape ``(Z, Y, X)`` (one intensity
slice per depth, non-negative, any overall scale unless stated) and is differentiable
in it with torch autograd (checked with ``gradcheck`` in float64), so a differentiable
forward model can be optimised against it.

- :func:`depth_dissimilarity` -- axial discrimination: the normalised zero-lag
  cross-correlation of the slices of every pair of depths, summed (or averaged) over
  pairs. Unitless; 1 per pair for identical slices, 0 for slices with disjoint support.
  **Lower is better** (depths easier to tell apart).
- :func:`mtf_support` -- lateral-resolution proxy: the fraction of a frequency band
  where the MTF of a slice exceeds a threshold, per depth; a sigmoid of width
  ``softness`` makes it smooth. Unitless in ``[0, 1]``; **higher is better**. (The thesis
  also names an MSE to the diffraction-limited MTF; the support fraction needs no
  reference lens and cannot be gamed by a constant, whose MTF is a single DC sample.)
- :func:`axial_fisher_information` / :func:`axial_crb` -- axial localisation of a point
  emitter at each depth under Poisson noise: expected counts
  ``mu_k(z) = photons * p_k(z) + background`` per pixel ``k``, Fisher information
  ``I(z) = sum_k (d mu_k / dz)^2 / mu_k`` (1/m^2) and the Cramer-Rao bound
  ``sqrt(1 / I(z))`` (metres, **lower is better**). ``d mu / dz`` is a finite
  difference between neighbouring depths of the stack (second order, also for unequal
  steps, as ``numpy.gradient(edge_order=2)``).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.fft import fft2


def _check_stack(psf: torch.Tensor, min_depths: int) -> None:
    if not isinstance(psf, torch.Tensor) or psf.ndim != 3 or psf.is_complex():
        raise ValueError(
            f"psf must be a real tensor (Z, Y, X); got {getattr(psf, 'shape', type(psf).__name__)}. "
            "Fix: pass the intensity stack, one slice per depth."
        )
    if psf.shape[0] < min_depths:
        raise ValueError(f"psf must hold at least {min_depths} depths; got {psf.shape[0]}. Fix: add depths.")


def depth_dissimilarity(psf: torch.Tensor, *, reduction: str = "mean", eps: float = 1e-30) -> torch.Tensor:
    """Normalised cross-correlation between the slices of all depth pairs (lower is better).

    ``sum_{i<j} <p_i, p_j> / (|p_i| |p_j|)`` with the L2 norms of the slices (zero lag,
    not mean-subtracted, so slices of disjoint support score 0 and identical ones 1).

    Parameters
    ----------
    psf : real tensor ``(Z, Y, X)``, ``Z >= 2``
    reduction : "mean" (over the ``Z (Z - 1) / 2`` pairs, in ``[0, 1]`` for non-negative
        stacks) or "sum" (the thesis' sum).
    eps : floor of the slice norms (an all-zero slice correlates 0 with everything).

    Returns
    -------
    0-d tensor, unitless.
    """
    _check_stack(psf, 2)
    if reduction not in ("mean", "sum"):
        raise ValueError(f"reduction must be 'mean' or 'sum'; got {reduction!r}.")
    flat = psf.reshape(psf.shape[0], -1)
    unit = flat / flat.norm(dim=1, keepdim=True).clamp_min(eps)
    gram = unit @ unit.T
    z = psf.shape[0]
    pairs = torch.triu(gram, diagonal=1).sum()
    return pairs / (z * (z - 1) / 2) if reduction == "mean" else pairs


def mtf(psf: torch.Tensor, *, eps: float = 1e-30) -> torch.Tensor:
    """MTF of each slice, ``|FFT(p)| / |FFT(p)(0)|``, in the unshifted FFT layout ``(Z, Y, X)``."""
    _check_stack(psf, 1)
    spectrum = fft2(psf.to(torch.complex128 if psf.dtype == torch.float64 else torch.complex64)).abs()
    return spectrum / spectrum[:, :1, :1].clamp_min(eps)


def band_mask(shape: tuple[int, int], band: float, device: torch.device | None = None) -> torch.Tensor:
    """Boolean ``(Y, X)`` mask of the FFT samples with radial frequency ``<= band`` cycles/pixel."""
    fy = torch.fft.fftfreq(shape[0], device=device, dtype=torch.float64)
    fx = torch.fft.fftfreq(shape[1], device=device, dtype=torch.float64)
    return fy[:, None] ** 2 + fx[None, :] ** 2 <= band**2 * (1.0 + 1e-12)


def mtf_support(
    psf: torch.Tensor, *, threshold: float = 0.1, band: float = 0.5, softness: float = 0.0
) -> torch.Tensor:
    """Fraction of the band where each slice's MTF exceeds ``threshold`` (higher is better).

    Parameters
    ----------
    psf : real tensor ``(Z, Y, X)`` (sampled on the pixels whose band is measured)
    threshold : MTF level counted as "transmitted", in ``(0, 1)``.
    band : radius of the frequency disc, cycles per pixel (``0.5``: up to Nyquist along
        the axes). For the incoherent cutoff ``2 NA / lambda`` of a PSF sampled at
        ``delta`` (sample plane) pass ``2 NA delta / lambda``.
    softness : 0 counts samples with a step (not differentiable); ``> 0`` replaces the
        step by ``sigmoid((MTF - threshold) / softness)`` (differentiable).

    Returns
    -------
    Tensor ``(Z,)``, values in ``[0, 1]``, unitless.
    """
    _check_stack(psf, 1)
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"threshold must lie in (0, 1); got {threshold!r}. Fix: e.g. 0.1.")
    if not (math.isfinite(band) and band > 0.0):
        raise ValueError(f"band must be > 0 cycles/pixel; got {band!r}. Fix: e.g. 0.5 (Nyquist).")
    if not (math.isfinite(softness) and softness >= 0.0):
        raise ValueError(f"softness must be >= 0; got {softness!r}. Fix: 0 (hard count) or e.g. 0.02.")
    inside = band_mask((psf.shape[-2], psf.shape[-1]), band, psf.device)
    values = mtf(psf)[:, inside]
    above = (
        (values > threshold).to(psf.dtype)
        if softness == 0.0
        else torch.sigmoid((values - threshold) / softness)
    )
    return above.mean(dim=1)


def _depth_derivative(values: torch.Tensor, depths: torch.Tensor) -> torch.Tensor:
    """``d values / d z`` along dim 0 at every depth, second order (``numpy.gradient(edge_order=2)``)."""
    z = depths.to(values.dtype)
    if values.shape[0] == 2:
        slope = (values[1] - values[0]) / (z[1] - z[0])
        return torch.stack([slope, slope])
    h = z[1:] - z[:-1]
    shape = (-1,) + (1,) * (values.ndim - 1)
    h1, h2 = h[:-1].reshape(shape), h[1:].reshape(shape)
    f0, f1, f2 = values[:-2], values[1:-1], values[2:]
    inner = (h1**2 * f2 - h2**2 * f0 + (h2**2 - h1**2) * f1) / (h1 * h2 * (h1 + h2))
    a, b = h[0], h[1]
    first = (
        -(2 * a + b) / (a * (a + b)) * values[0]
        + (a + b) / (a * b) * values[1]
        - a / (b * (a + b)) * values[2]
    )
    a, b = h[-1], h[-2]
    last = (
        (2 * a + b) / (a * (a + b)) * values[-1]
        - (a + b) / (a * b) * values[-2]
        + a / (b * (a + b)) * values[-3]
    )
    return torch.cat([first[None], inner, last[None]])


def axial_fisher_information(
    psf: torch.Tensor,
    depths: torch.Tensor,
    *,
    photons: float,
    background: float = 0.0,
    normalize: bool = True,
    min_counts: float = 1e-12,
) -> torch.Tensor:
    """Fisher information about the emitter depth, per depth of the stack, 1/m^2 (higher is better).

    Parameters
    ----------
    psf : real tensor ``(Z, Y, X)``, non-negative
    depths : tensor ``(Z,)``, strictly increasing, metres
    photons : expected detected signal photons per emitter (> 0)
    background : expected background photons per pixel (>= 0)
    normalize : True: each slice is scaled to sum 1 first (``photons`` are then the
        detected photons at every depth); False: ``psf`` already holds detection
        probabilities per pixel (its sums may vary with depth).
    min_counts : floor of ``mu`` (photons) where a pixel expects no photon at all
        (without background); with ``background > 0`` it never acts.

    Returns
    -------
    Tensor ``(Z,)`` in 1/m^2.
    """
    _check_stack(psf, 2)
    depths = torch.as_tensor(depths, dtype=torch.float64, device=psf.device)
    if depths.shape != (psf.shape[0],) or not bool(torch.all(depths[1:] > depths[:-1])):
        raise ValueError(
            f"depths must be a strictly increasing tensor of {psf.shape[0]} depths in metres; got "
            f"{tuple(depths.shape)} {depths.tolist()[:4]}. Fix: e.g. torch.linspace(-50e-6, 50e-6, Z)."
        )
    if not (math.isfinite(photons) and photons > 0.0):
        raise ValueError(
            f"photons must be > 0; got {photons!r}. Fix: e.g. 1000 detected photons per emitter."
        )
    if not (math.isfinite(background) and background >= 0.0):
        raise ValueError(f"background must be >= 0 photons per pixel; got {background!r}. Fix: e.g. 10.")
    total = psf.sum(dim=(1, 2), keepdim=True).clamp_min(torch.finfo(psf.dtype).tiny)  # zero slice: no NaN
    p = psf / total if normalize else psf
    mu = photons * p + background
    slope = _depth_derivative(mu, depths)
    return (slope**2 / mu.clamp_min(min_counts)).sum(dim=(1, 2))


def axial_crb(
    psf: torch.Tensor,
    depths: torch.Tensor,
    *,
    photons: float,
    background: float = 0.0,
    normalize: bool = True,
) -> torch.Tensor:
    """Cramer-Rao bound ``1 / sqrt(I(z))`` on the emitter depth, per depth, metres (lower is better).

    See :func:`axial_fisher_information` for the parameters; a depth with zero information
    has an infinite bound.
    """
    info = axial_fisher_information(psf, depths, photons=photons, background=background, normalize=normalize)
    return info.rsqrt()
