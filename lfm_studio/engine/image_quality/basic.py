"""MSE, PSNR with an explicit data range, and scale matching of an estimate to the truth.

A reconstruction's intensity scale is arbitrary (Richardson-Lucy returns voxel values
in image counts per unit PSF energy, Wiener in whatever the PSF normalisation gives);
:func:`match_scale` puts an estimate on the truth's scale before comparing, when the
question is "is the structure right" rather than "are the numbers right".

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import torch

from lfm_studio.engine.errors import require_finite_tensor

Normalization = Literal["none", "scale", "affine", "sum"]
NORMALIZATIONS: tuple[str, ...] = ("none", "scale", "affine", "sum")


def as_pair(truth, estimate, *, name: str = "metric") -> tuple[torch.Tensor, torch.Tensor]:
    """``truth`` and ``estimate`` as float64 tensors on one device, checked for shape and finiteness."""
    tensors = []
    for label, value in (("truth", truth), ("estimate", estimate)):
        if isinstance(value, np.ndarray):
            value = torch.from_numpy(np.ascontiguousarray(value))
        if not isinstance(value, torch.Tensor):
            raise TypeError(
                f"{name}: {label} must be a torch.Tensor or numpy array; got {type(value).__name__}."
            )
        if value.is_complex():
            raise TypeError(
                f"{name}: {label} must be real; got {value.dtype}. Fix: compare abs(x) or x.real."
            )
        tensors.append(value)
    truth, estimate = tensors
    if truth.shape != estimate.shape:
        raise ValueError(
            f"{name}: truth has shape {tuple(truth.shape)} but estimate has shape {tuple(estimate.shape)}. "
            "Fix: compare volumes on the same grid (same depths and lateral size)."
        )
    if truth.numel() == 0:
        raise ValueError(f"{name}: the inputs are empty (shape {tuple(truth.shape)}).")
    estimate = estimate.to(device=truth.device, dtype=torch.float64)
    truth = truth.to(dtype=torch.float64)
    require_finite_tensor(f"{name}: truth", truth.detach())
    require_finite_tensor(f"{name}: estimate", estimate.detach())
    return truth, estimate


def data_range_of(truth, data_range: float | None = None) -> float:
    """The data range ``R`` of PSNR/SSIM: ``data_range`` if given, else ``truth.max() - truth.min()``.

    Raises ``ValueError`` for a non-positive range (e.g. a constant truth without an
    explicit ``data_range``).
    """
    if data_range is None:
        truth = torch.as_tensor(truth).detach()
        value = float(truth.max() - truth.min())
        if not value > 0:
            raise ValueError(
                f"data_range: the truth is constant (max - min = {value:g}), so its range cannot set the "
                "PSNR/SSIM scale. Fix: pass data_range explicitly (e.g. the largest value a voxel can take)."
            )
        return value
    value = float(data_range)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"data_range must be a finite number > 0 (in data units); got {data_range!r}.")
    return value


def mse(truth, estimate) -> torch.Tensor:
    """Mean squared error ``mean((estimate - truth)^2)`` over all elements (float64 0-d tensor)."""
    truth, estimate = as_pair(truth, estimate, name="mse")
    return (estimate - truth).square().mean()


def psnr(truth, estimate, *, data_range: float | None = None) -> torch.Tensor:
    """Peak signal-to-noise ratio ``10 log10(R^2 / MSE)`` in dB.

    Parameters
    ----------
    truth, estimate : tensors of one shape (any number of dimensions).
    data_range : float, optional
        ``R`` in data units; default the truth's ``max - min``. Thesis eq. 2.3 uses
        ``R = 255`` for 8-bit images: pass ``data_range=255`` to get that convention.

    Returns
    -------
    0-d float64 tensor; ``+inf`` when the inputs are identical.
    """
    truth, estimate = as_pair(truth, estimate, name="psnr")
    peak = data_range_of(truth, data_range)
    error = (estimate - truth).square().mean()
    return 10.0 * torch.log10(peak**2 / error)


def match_scale(estimate, truth, mode: Normalization = "scale") -> torch.Tensor:
    """``estimate`` put on the intensity scale of ``truth`` (float64), by least squares.

    Modes
    -----
    ``"none"``: unchanged. ``"scale"``: ``a * estimate`` with ``a = <t, e> / <e, e>``
    (minimises ``|a e - t|^2``; the usual choice for a reconstruction whose absolute
    scale is arbitrary). ``"affine"``: ``a * estimate + c`` fitted by least squares
    (also removes a constant offset, e.g. an unsubtracted background). ``"sum"``:
    ``estimate * sum(t) / sum(e)`` (same total intensity).
    An all-zero estimate is returned unchanged.
    """
    if mode not in NORMALIZATIONS:
        raise ValueError(f"normalize must be one of {NORMALIZATIONS}; got {mode!r}.")
    truth, estimate = as_pair(truth, estimate, name="match_scale")
    if mode == "none":
        return estimate
    e, t = estimate.reshape(-1), truth.reshape(-1)
    if mode == "scale":
        energy = (e * e).sum()
        return estimate if float(energy) == 0.0 else estimate * ((e * t).sum() / energy)
    if mode == "sum":
        total = e.sum()
        return estimate if float(total) == 0.0 else estimate * (t.sum() / total)
    e_mean, t_mean = e.mean(), t.mean()
    variance = (e - e_mean).square().sum()
    if float(variance) == 0.0:  # constant estimate: only the offset can be fitted
        return torch.full_like(estimate, float(t_mean))
    slope = ((e - e_mean) * (t - t_mean)).sum() / variance
    return slope * (estimate - e_mean) + t_mean
