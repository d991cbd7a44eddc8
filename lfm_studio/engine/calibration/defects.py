"""Dark subtraction and defective pixels (hot, dead): detection and median replacement.

- A *hot* pixel reads far above the brightest of its 8 neighbours: by more than
  ``n_sigma`` robust standard deviations of the pixel noise (1.4826 x the median absolute
  deviation of ``frame - median3x3(frame)``). Light never peaks on one pixel of a lenslet
  disk, so disk edges are not taken for hot pixels. Hot pixels sit in the sensor: the dark
  frame shows them best; in the radiometry frame, where shot noise grows with the light,
  only pixels also ``relative`` (0.25) above their brightest neighbour count.
- A *dead* pixel of a radiometry frame reads below ``DEAD_FRACTION`` of the darkest of its
  8 neighbours while that neighbour is bright (over half the frame's ``LIT_QUANTILE``
  quantile, a typical lit pixel that hot pixels do not move): a pixel inside a lit lenslet
  disk that does not respond. The unlit gaps between disks always have a dark neighbour.
- Defects are replaced by the median of their non-defective 3 x 3 neighbours.
"""

from __future__ import annotations

import math

import torch

DEAD_FRACTION = 0.05
LIT_QUANTILE = 0.9
_ROWS_PER_CHUNK = 256  # bounds the (rows, X, 9) neighbourhood tensor to a few tens of MB


def subtract_dark(frame: torch.Tensor, dark: torch.Tensor | float) -> torch.Tensor:
    """``frame - dark`` (float64); ``dark`` is a frame of the same shape or a level, ADU."""
    if isinstance(dark, torch.Tensor) and dark.shape != frame.shape:
        raise ValueError(
            f"dark frame shape {tuple(dark.shape)} differs from the frame's {tuple(frame.shape)}. "
            "Fix: record the dark frame with the same camera region (ROI) and binning."
        )
    return frame.to(torch.float64) - (dark.to(torch.float64) if isinstance(dark, torch.Tensor) else dark)


def _neighbourhoods(image: torch.Tensor, rows: slice) -> torch.Tensor:
    """(rows, X, 9) 3 x 3 neighbourhoods of the given rows (edge pixels replicated beyond the frame)."""
    ny = image.shape[0]
    start, stop = rows.start, rows.stop
    lo, hi = max(start - 1, 0), min(stop + 1, ny)
    block = image[lo:hi][None, None]
    pad = (1, 1, int(start == 0), int(stop == ny))
    block = torch.nn.functional.pad(block, pad, mode="replicate")[0, 0]
    return block.unfold(0, 3, 1).unfold(1, 3, 1).reshape(stop - start, image.shape[1], 9)


def median3x3(image: torch.Tensor, ignore: torch.Tensor | None = None) -> torch.Tensor:
    """3 x 3 median of ``image`` (Y, X); pixels where ``ignore`` is True do not vote."""
    data = image.to(torch.float32)
    if ignore is not None:
        data = torch.where(ignore, torch.full_like(data, float("nan")), data)
    out = torch.empty_like(data)
    for start in range(0, data.shape[0], _ROWS_PER_CHUNK):
        rows = slice(start, min(start + _ROWS_PER_CHUNK, data.shape[0]))
        out[rows] = _neighbourhoods(data, rows).nanmedian(dim=-1).values
    return out


def neighbour_extreme(image: torch.Tensor, largest: bool) -> torch.Tensor:
    """Largest (or smallest) of each pixel's 8 neighbours inside the frame, (Y, X) float32."""
    data = image.to(torch.float32)
    ny, nx = data.shape
    fill = -math.inf if largest else math.inf
    padded = torch.nn.functional.pad(data[None, None], (1, 1, 1, 1), value=fill)[0, 0]
    pick = torch.maximum if largest else torch.minimum
    out = torch.full_like(data, fill)
    for dy in range(3):
        for dx in range(3):
            if dy != 1 or dx != 1:
                out = pick(out, padded[dy : dy + ny, dx : dx + nx])
    return out


def _noise_sigma(frame: torch.Tensor) -> float:
    """Robust pixel-noise sigma: 1.4826 MAD of ``frame - median3x3(frame)`` on the central 256 rows."""
    middle = frame.shape[0] // 2
    sample = frame[max(0, middle - 128) : middle + 128]
    residual = (sample.to(torch.float32) - median3x3(sample)).reshape(-1)
    return 1.4826 * float((residual - residual.median()).abs().median())


def hot_pixels(frame: torch.Tensor, *, n_sigma: float = 8.0, relative: float = 0.0) -> torch.Tensor:
    """(Y, X) bool: pixels above the brightest of their 8 neighbours by more than ``n_sigma`` noise sigmas.

    ``relative`` > 0 also asks the excess to be over ``relative`` times that neighbour:
    use it on lit, dark-subtracted frames, where shot noise grows with the signal; on a
    dark frame the noise is uniform and ``relative=0`` finds weak hot pixels too.
    """
    data = frame.to(torch.float32)
    high = neighbour_extreme(data, largest=True)
    excess = data - high
    return (excess > n_sigma * max(_noise_sigma(data), 1e-6)) & (excess > relative * high.clamp_min(0.0))


def dead_pixels(frame: torch.Tensor) -> torch.Tensor:
    """(Y, X) bool: pixels below ``DEAD_FRACTION`` of their darkest neighbour, that neighbour lit."""
    data = frame.to(torch.float32)
    low = neighbour_extreme(data, largest=False)
    sample = data.reshape(-1)[:: max(1, data.numel() // 1_000_000)]
    bright = float(torch.quantile(sample, LIT_QUANTILE))
    return (low > 0.5 * bright) & (data < DEAD_FRACTION * low)


def replace_defects(frame: torch.Tensor, defects: torch.Tensor) -> torch.Tensor:
    """``frame`` with each defect replaced by the median of its non-defective 3 x 3 neighbours.

    A defect whose 8 neighbours are all defects (or outside the frame) keeps its value.
    """
    if defects.shape != frame.shape:
        raise ValueError(
            f"defect mask shape {tuple(defects.shape)} differs from the frame's {tuple(frame.shape)}."
        )
    out = frame.clone()
    where = torch.nonzero(defects)
    if where.shape[0] == 0:
        return out
    nx = frame.shape[1]
    nan = torch.tensor(float("nan"), dtype=frame.dtype)
    padded = torch.nn.functional.pad(
        torch.where(defects, nan, frame)[None, None], (1, 1, 1, 1), value=float("nan")
    )
    flat = padded.reshape(-1)
    offsets = torch.tensor([dy * (nx + 2) + dx for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
    index = (where[:, 0] + 1) * (nx + 2) + (where[:, 1] + 1)
    fill = flat[index[:, None] + offsets].nanmedian(dim=1).values
    keep = torch.isnan(fill)
    out[where[:, 0], where[:, 1]] = torch.where(keep, frame[where[:, 0], where[:, 1]], fill)
    return out
