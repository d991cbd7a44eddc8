"""Fourier LFM flat field: one smooth gain map per sub-image, from the radiometry frame.

In a Fourier LFM each lenslet forms its own image of the field stop, and each sees the
objective's pupil through a different part of the relay: vignetting differs from one
sub-image to the next (a gain), and across each (a slope). A single frame-wide envelope
(conventional LFM, :mod:`.flat_field`) cannot follow that, so each sub-image ``l`` gets its
own polynomial ``g_l(u, w)`` of degree ``DEGREE`` in local coordinates
``u = (y - c_y) / R``, ``w = (x - c_x) / R`` (``c`` the measured centre, ``R`` half the
nominal sub-image diameter), fitted by least squares to the radiometry pixels within
``INTERIOR`` of ``R`` (the disk's soft edge is left out). The gains are normalised so that
the median over the fitted sub-images of their mean over the interior is 1; a corrected
frame is the frame divided by ``g_l`` inside sub-image ``l`` (pixels within ``R + 1`` px
of its centre, the nearest centre where two overlap) and unchanged outside every
sub-image. Sub-images flagged ``DIM`` (blocked) or with too few pixels on the frame keep a
gain of 1 rather than amplifying noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lfm_studio.engine.calibration.grid_fit import DIM

DEGREE = 2
INTERIOR = 0.9  # fit on pixels within this fraction of the nominal radius
MIN_GAIN = 0.05  # gains below this (of the median) are clamped, as for the frame-wide envelope
_TERMS = [(a, b) for a in range(DEGREE + 1) for b in range(DEGREE + 1 - a)]


@dataclass(frozen=True)
class SubImageFlat:
    """Per-sub-image gain polynomials.

    Attributes
    ----------
    coefficients : (L, T) float64, the coefficients of ``u^a w^b`` (``a + b <= DEGREE``, in
        the order ``(0,0), (0,1), ..., (1,0), ...``) per sub-image, design lenslet order.
    radius : R, half the nominal sub-image diameter, px (the local coordinate unit).
    """

    coefficients: torch.Tensor
    radius: float

    def __post_init__(self) -> None:
        if self.coefficients.ndim != 2 or self.coefficients.shape[1] != len(_TERMS):
            raise ValueError(
                f"SubImageFlat.coefficients must be (L, {len(_TERMS)}); got {tuple(self.coefficients.shape)}."
            )
        if not self.radius > 0:
            raise ValueError(f"SubImageFlat.radius must be > 0 px; got {self.radius}.")


def _basis(u: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    return torch.stack([u**a * w**b for a, b in _TERMS], dim=-1)


def _window(centre: torch.Tensor, reach: float, shape: tuple[int, int]):
    """Pixel coordinates (yy, xx) float64 of the box of half-size ``reach`` around ``centre``, clipped."""
    cy, cx = (float(v) for v in centre)
    y0, y1 = max(int(cy - reach), 0), min(int(cy + reach) + 2, shape[0])
    x0, x1 = max(int(cx - reach), 0), min(int(cx + reach) + 2, shape[1])
    yy, xx = torch.meshgrid(
        torch.arange(y0, y1, dtype=torch.float64), torch.arange(x0, x1, dtype=torch.float64), indexing="ij"
    )
    return (slice(y0, y1), slice(x0, x1)), yy, xx


def fit_sub_image_flat(
    image: torch.Tensor, centres: torch.Tensor, flags: torch.Tensor, diameter: float
) -> SubImageFlat:
    """Gain polynomials of a dark-subtracted radiometry ``image`` (Y, X) around ``centres`` (L, 2) px.

    ``flags`` (L,) are the sub-image fit's flags (``DIM`` ones keep gain 1); ``diameter`` is
    the nominal sub-image diameter, px.
    """
    radius = 0.5 * float(diameter)
    shape = (int(image.shape[0]), int(image.shape[1]))
    identity = torch.zeros(len(_TERMS), dtype=torch.float64)
    identity[0] = 1.0
    rows: list[torch.Tensor | None] = []
    means: list[float] = []
    for centre, flag in zip(centres.to(torch.float64), flags.tolist(), strict=True):
        box, yy, xx = _window(centre, INTERIOR * radius, shape)
        u, w = (yy - centre[0]) / radius, (xx - centre[1]) / radius
        inside = u**2 + w**2 <= INTERIOR**2
        if flag & DIM or int(inside.sum()) < 4 * len(_TERMS):
            rows.append(None)
            continue
        basis = _basis(u[inside], w[inside])
        values = image[box].to(torch.float64)[inside]
        solution = torch.linalg.lstsq(basis, values[:, None]).solution[:, 0]
        rows.append(solution)
        means.append(float((basis @ solution).mean()))
    if not means:
        raise ValueError(
            "no sub-image is whole and lit enough on the radiometry frame for a flat field. "
            "Fix: check that the radiometry frame shows the sub-images (a uniform fluorescent slide)."
        )
    scale = float(torch.quantile(torch.tensor(means, dtype=torch.float64), 0.5))
    if not scale > 0:
        raise ValueError(
            f"the sub-images of the radiometry frame carry no light above the dark level (median {scale:.3g}). "
            "Fix: record the radiometry frame with more light, or check the dark frame."
        )
    coefficients = torch.stack([identity if row is None else row / scale for row in rows])
    return SubImageFlat(coefficients=coefficients, radius=radius)


def sub_image_flat_map(flat: SubImageFlat, centres: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """The gain over a frame of ``shape``: ``g_l`` within ``R + 1`` px of centre ``l``, else 1; (Y, X) float64."""
    gain = torch.ones(shape, dtype=torch.float64)
    distance = torch.full(shape, float("inf"), dtype=torch.float64)
    reach = flat.radius + 1.0
    for centre, coefficients in zip(centres.to(torch.float64), flat.coefficients, strict=True):
        box, yy, xx = _window(centre, reach, shape)
        u, w = (yy - centre[0]) / flat.radius, (xx - centre[1]) / flat.radius
        r = torch.sqrt(u**2 + w**2) * flat.radius
        nearer = (r <= reach) & (r < distance[box])
        values = (_basis(u, w) @ coefficients).clamp_min(MIN_GAIN)
        gain[box] = torch.where(nearer, values, gain[box])
        distance[box] = torch.where(nearer, r, distance[box])
    return gain
