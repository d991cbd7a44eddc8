"""Per-depth quality curves and a one-call comparison report (what ``lfm-studio metrics`` prints).

A light-field reconstruction is not equally good at every depth (resolution and
artefacts change with the distance from the native focal plane), so quality is also
reported per z slice: 2D PSNR and SSIM of each slice, all with ONE data range (by
default the range of the whole truth volume), so the curve values are comparable.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from lfm_studio.engine.image_quality.basic import Normalization, as_pair, data_range_of, match_scale
from lfm_studio.engine.image_quality.ssim import TRUNCATE, ssim, window_radius


@dataclass(frozen=True)
class DepthCurves:
    """Quality per z slice (float64 tensors of shape ``(Z,)``); ``depths`` in metres if known."""

    mse: torch.Tensor
    psnr: torch.Tensor
    ssim: torch.Tensor
    depths: tuple[float, ...] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready lists (``null`` for an infinite PSNR of an exact slice); depths in um."""
        out = {
            "mse": [_number(v) for v in self.mse.tolist()],
            "psnr_db": [_number(v) for v in self.psnr.tolist()],
            "ssim": [_number(v) for v in self.ssim.tolist()],
        }
        if self.depths is not None:
            out["depths_um"] = [z * 1e6 for z in self.depths]
        return out


def depth_curves(
    truth,
    estimate,
    *,
    data_range: float | None = None,
    sigma: float = 1.5,
    depths: Sequence[float] | None = None,
) -> DepthCurves:
    """MSE, PSNR and 2D SSIM of each z slice of volumes ``(Z, Y, X)``.

    ``data_range`` is shared by all slices (default: the whole truth volume's
    ``max - min``, so a slice without objects is scored on the volume's scale instead
    of failing); ``sigma`` is the SSIM window of each slice (samples).
    """
    truth, estimate = as_pair(truth, estimate, name="depth_curves")
    if truth.ndim != 3:
        raise ValueError(f"depth_curves needs volumes (Z, Y, X); got shape {tuple(truth.shape)}.")
    if depths is not None and len(depths) != truth.shape[0]:
        raise ValueError(f"depth_curves: {truth.shape[0]} slices but {len(depths)} depths.")
    r = data_range_of(truth, data_range)
    errors = (estimate - truth).square().mean(dim=(1, 2))
    psnr = 10.0 * torch.log10(r**2 / errors)
    ssims = torch.stack([ssim(t, e, data_range=r, sigma=sigma) for t, e in zip(truth, estimate, strict=True)])
    return DepthCurves(errors, psnr, ssims, None if depths is None else tuple(float(z) for z in depths))


def volume_sigma(shape: Sequence[int], sigma: float = 1.5, truncate: float = TRUNCATE) -> tuple[float, ...]:
    """SSIM window per axis for :func:`compare`: ``sigma`` along every axis long enough for the window,
    ``0`` (no smoothing across that axis) along a shorter one (e.g. a volume of 5 depths)."""
    window = 2 * window_radius(sigma, truncate) + 1
    return tuple(sigma if n >= window else 0.0 for n in shape)


@dataclass(frozen=True)
class MetricReport:
    """The outcome of :func:`compare` (plain floats; ``inf`` PSNR for identical inputs)."""

    mse: float
    psnr: float
    ssim: float
    data_range: float
    normalize: str
    scale: float | None
    ssim_sigma: tuple[float, ...]
    shape: tuple[int, ...]
    per_depth: DepthCurves | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary (``null`` where PSNR is infinite)."""
        out: dict[str, Any] = {
            "shape": list(self.shape),
            "mse": self.mse,
            "psnr_db": _number(self.psnr),
            "ssim": self.ssim,
            "data_range": self.data_range,
            "normalize": self.normalize,
            "scale": self.scale,
            "ssim_sigma_samples": list(self.ssim_sigma),
        }
        if self.per_depth is not None:
            out["per_depth"] = self.per_depth.to_dict()
        return out


def compare(
    truth,
    estimate,
    *,
    data_range: float | None = None,
    normalize: Normalization = "none",
    per_depth: bool = False,
    sigma: float = 1.5,
    depths: Sequence[float] | None = None,
) -> MetricReport:
    """MSE, PSNR and SSIM of ``estimate`` against ``truth`` (images or volumes), optionally per depth.

    Parameters
    ----------
    truth, estimate : tensors of one shape, ``(Y, X)`` or ``(Z, Y, X)``.
    data_range : float, optional
        Shared by PSNR and SSIM; default the truth's ``max - min``.
    normalize : "none" | "scale" | "affine" | "sum"
        Put ``estimate`` on the truth's scale first (see :func:`match_scale`);
        ``report.scale`` is the factor applied (``None`` for "none"/"affine").
    per_depth : also compute :func:`depth_curves` (volumes only).
    sigma : SSIM window in samples; along an axis shorter than the window (typically
        z with few depths) no smoothing is done (see :func:`volume_sigma`), and the
        report says which sigmas were used.
    depths : depth of each slice in metres, carried into the per-depth curves.
    """
    truth, estimate = as_pair(truth, estimate, name="compare")
    r = data_range_of(truth, data_range)
    matched = match_scale(estimate, truth, normalize)
    scale = None
    if normalize in ("scale", "sum"):
        e, m = estimate.reshape(-1), matched.reshape(-1)
        scale = float((m @ e) / (e @ e)) if float(e @ e) > 0 else 1.0
    sigmas = volume_sigma(truth.shape, sigma)
    if all(s == 0 for s in sigmas[-2:]):
        raise ValueError(
            f"compare: the lateral size {tuple(truth.shape[-2:])} is smaller than the 11-sample SSIM window. "
            "Fix: compare larger images or volumes."
        )
    error = float((matched - truth).square().mean())
    return MetricReport(
        mse=error,
        psnr=10.0 * math.log10(r**2 / error) if error > 0 else math.inf,
        ssim=float(ssim(truth, matched, data_range=r, sigma=sigmas)),
        data_range=r,
        normalize=normalize,
        scale=scale,
        ssim_sigma=sigmas,
        shape=tuple(truth.shape),
        per_depth=depth_curves(truth, matched, data_range=r, sigma=sigma, depths=depths)
        if per_depth
        else None,
    )


def _number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None
