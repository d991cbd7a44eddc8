"""Sub-pixel centroids of bright spots in windows around predicted positions.

Each spot is measured inside a soft circular window of radius ``radius`` px centred on
its current estimate (pixel weight ``clip(radius - r + 1/2, 0, 1)``) from the
background-subtracted, non-negative intensity; the window is re-centred on the new
centroid ``iterations`` times. A symmetric spot then gives an unbiased centre: a
background inside a window that is off centre pulls the centroid towards the window
centre, and re-centring removes that pull.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class Centroids:
    """Measured spots.

    Attributes
    ----------
    centres : (L, 2) float64 (y, x) px.
    mass : (L,) float64, background-subtracted intensity inside the window (ADU * px).
    """

    centres: torch.Tensor
    mass: torch.Tensor


def measure_centroids(
    image: torch.Tensor,
    start: torch.Tensor,
    *,
    radius: float,
    background: float = 0.0,
    iterations: int = 3,
) -> Centroids:
    """Centroids of the spots of ``image`` (Y, X) near ``start`` (L, 2) (y, x) px.

    Parameters
    ----------
    image : (Y, X) real tensor.
    start : (L, 2) first guesses, px.
    radius : window radius, px (about half the spot spacing).
    background : subtracted from every pixel before weighting (negative results count 0).
    iterations : re-centring passes (>= 1).
    """
    ny, nx = image.shape
    half = int(radius) + 2
    size = 2 * half + 1
    # Zero padding by the window's reach: every window reads inside the padded frame.
    padded = torch.nn.functional.pad(
        (image.to(torch.float32) - background).clamp_min(0.0), (half + 1, half + 1, half + 1, half + 1)
    )
    width = nx + 2 * half + 2
    flat = padded.reshape(-1)
    offsets = torch.arange(-half, half + 1, dtype=torch.float32)
    window_index = (torch.arange(size)[:, None] * width + torch.arange(size)[None, :]).reshape(-1)
    centres = start.to(torch.float64).clone()
    mass = torch.zeros(centres.shape[0], dtype=torch.float64)
    for _ in range(max(1, iterations)):
        base = centres.round()
        frac = (centres - base).to(torch.float32)
        base = base.long().clamp(min=torch.tensor([-1, -1]), max=torch.tensor([ny, nx]))
        corner = (base[:, 0] + 1) * width + (base[:, 1] + 1)  # window's top-left in the padded frame
        values = flat[corner[:, None] + window_index].reshape(-1, size, size)
        dy = offsets[None, :, None] - frac[:, 0, None, None]
        dx = offsets[None, None, :] - frac[:, 1, None, None]
        w = (radius + 0.5 - torch.sqrt(dy * dy + dx * dx)).clamp_(0.0, 1.0).mul_(values)
        mass = w.sum(dim=(1, 2)).to(torch.float64)
        safe = mass.clamp_min(1e-30)
        shift = torch.stack(((w * dy).sum(dim=(1, 2)) / safe, (w * dx).sum(dim=(1, 2)) / safe), dim=1)
        centres = centres + torch.where(mass[:, None] > 0, shift.to(torch.float64), torch.zeros_like(centres))
    return Centroids(centres=centres, mass=mass)
