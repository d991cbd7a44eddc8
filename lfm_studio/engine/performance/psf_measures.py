"""Resolution and depth of field measured on a PSF stack (simulated or from beads).

All functions take a :class:`~lfm_studio.engine.psf_stack.PSFStack` with data
``(Z, Y, X)`` and return sample-side lengths in metres (sensor lengths divided by
the stack's magnification), or None when the quantity cannot be read from the stack
(a curve that does not fall to the level before the stack ends).

- **Best focus**: the slice with the highest energy concentration ``sum(I^2) / sum(I)^2``
  (a defocused spot spreads its power over more pixels).
- **Lateral FWHM**: profiles along x and y through the brightest pixel of a slice (one
  sub-image spot), the sub-sample peak and the two half-maximum crossings read from
  the 4-point Lagrange interpolant (:mod:`.interpolation`); the mean of the x and y
  widths. Pixel integration is part of the measurement, as for a camera.
- **Axial FWHM** (default ``method="correlation"``): the normalised correlation
  ``c(z) = <P(z), P(z0)> / (|P(z)| |P(z0)|)`` of whole sensor images against the
  reference depth ``z0``; its full width at ``c = 1/2``. In a light-field PSF depth is
  encoded by the parallax of the views as much as by defocus, and the correlation of
  the whole pattern sees both. For two copies of a spot shifted by ``s`` it is the
  spot's autocorrelation, e.g. ``exp(-s^2 / (4 sigma^2))`` for a Gaussian. ``method="peak"``
  instead takes the full width at half maximum of the brightest pixel near the
  reference spot versus depth (the axial extent of one view's focus, what a
  widefield microscope calls axial FWHM).
- **Depth of field**: the depths at which the lateral FWHM stays within
  ``criterion`` (default ``sqrt(2)``, the Rayleigh-range convention of a beam widening
  by sqrt 2) of its best value; runs of such slices are extended to the interpolated
  crossing and their lengths summed (multifocal arrays give several runs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import torch

from lfm_studio.engine.performance.interpolation import full_width_at
from lfm_studio.engine.psf_stack import PSFStack

DOF_CRITERION = math.sqrt(2.0)
"""Default lateral-FWHM growth that ends the depth of field."""


def stack_data(psf: PSFStack) -> torch.Tensor:
    """The stack's data ``(Z, Y, X)``, detached (dtype kept: a full sensor stack is large).

    Raises ValueError for batched stacks. Small pieces (profiles, patches) are read in
    float64 by the functions that use them.
    """
    if psf.data.ndim != 3:
        raise ValueError(
            f"design metrics need a PSF stack of shape (Z, Y, X); got shape {tuple(psf.data.shape)}. "
            "Fix: pick one batch element, e.g. psf.with_data(psf.data[0])."
        )
    return psf.data.detach()


def depth_index(psf: PSFStack, depth: float | None) -> int:
    """Index of the slice nearest ``depth`` (m), or of the best-focus slice when None."""
    if depth is None:
        return best_focus_index(psf)
    return min(range(len(psf.depths)), key=lambda i: abs(psf.depths[i] - depth))


def sharpness(image: torch.Tensor) -> float:
    """Energy concentration ``sum(I^2) / sum(I)^2`` of an image (1 / number of lit pixels)."""
    flat = image.to(torch.float64).flatten()
    total = float(flat.sum())
    return float(flat.square().sum()) / total**2 if total > 0.0 else 0.0


def best_focus_index(psf: PSFStack) -> int:
    """Index of the sharpest slice (largest :func:`sharpness`): the best-focused spots.

    Energy concentration, not the brightest pixel: with spots 2-3 pixels wide the
    brightest pixel swings by tens of percent with the spot's sub-pixel position.
    """
    data = stack_data(psf)
    scores = [sharpness(image) for image in data]
    return max(range(len(scores)), key=scores.__getitem__)


def peak_pixel(image: torch.Tensor) -> tuple[int, int]:
    """``(row, col)`` of the brightest pixel of ``image (Y, X)``."""
    flat = int(torch.argmax(image))
    return flat // image.shape[1], flat % image.shape[1]


def spot_fwhm_pixels(image: torch.Tensor) -> tuple[float | None, float | None]:
    """FWHM along x and y (sensor pixels) of the spot at the brightest pixel of ``image``."""
    row, col = peak_pixel(image)
    return full_width_at(image[row, :], 0.5, col), full_width_at(image[:, col], 0.5, row)


def lateral_fwhm(psf: PSFStack, *, depth: float | None = None) -> float | None:
    """Mean x/y FWHM of the brightest spot at ``depth`` (default: best focus), sample side, m."""
    data = stack_data(psf)
    fx, fy = spot_fwhm_pixels(data[depth_index(psf, depth)])
    if fx is None or fy is None:
        return None
    return 0.5 * (fx + fy) * psf.object_pixel_size


def depth_order(psf: PSFStack) -> tuple[list[int], torch.Tensor]:
    """Slice indices sorted by depth, and the sorted depths (float64 tensor, m)."""
    order = sorted(range(len(psf.depths)), key=lambda i: psf.depths[i])
    return order, torch.tensor([psf.depths[i] for i in order], dtype=torch.float64)


def correlation_curve(psf: PSFStack, reference: int) -> torch.Tensor:
    """Normalised correlation of every slice with slice ``reference``, float64, shape ``(Z,)``."""
    data = stack_data(psf)
    ref = data[reference].to(torch.float64).flatten()
    ref_norm = ref.norm()
    values = []
    for image in data:  # one slice at a time in float64: bounded memory
        flat = image.to(torch.float64).flatten()
        denom = (flat.norm() * ref_norm).clamp_min(torch.finfo(torch.float64).tiny)
        values.append(torch.dot(flat, ref) / denom)
    return torch.stack(values)


def peak_curve(psf: PSFStack, reference: int, window: int) -> torch.Tensor:
    """Brightest pixel within ``window`` pixels of the reference spot, per slice, shape ``(Z,)``."""
    data = stack_data(psf)
    row, col = peak_pixel(data[reference])
    patch = data[:, max(row - window, 0) : row + window + 1, max(col - window, 0) : col + window + 1]
    return patch.flatten(1).amax(dim=1).to(torch.float64)


def axial_fwhm(
    psf: PSFStack,
    *,
    depth: float | None = None,
    method: Literal["correlation", "peak"] = "correlation",
    window: int | None = None,
) -> float | None:
    """Axial full width at half maximum around ``depth`` (default: best focus), m.

    Parameters
    ----------
    psf : PSF stack ``(Z, Y, X)``; depths need not be evenly spaced or sorted.
    depth : reference depth in metres (the nearest slice is used).
    method : ``"correlation"`` (whole-pattern similarity, default) or ``"peak"``
        (brightest pixel near the reference spot); see the module docstring.
    window : half-size in pixels of the search box of ``"peak"`` (default: 3 lateral FWHMs).

    Returns
    -------
    The width in metres, or None when the curve does not fall to half on both sides.
    """
    reference = depth_index(psf, depth)
    if method == "correlation":
        curve = correlation_curve(psf, reference)
    elif method == "peak":
        if window is None:
            fx, fy = spot_fwhm_pixels(stack_data(psf)[reference])
            window = max(3, round(3.0 * max(fx or 1.0, fy or 1.0)))
        curve = peak_curve(psf, reference, window)
    else:
        raise ValueError(f"method must be 'correlation' or 'peak'; got {method!r}.")
    order, nodes = depth_order(psf)
    values = curve[order]
    start = order.index(reference) if method == "correlation" else int(torch.argmax(values))
    if values.numel() < 3:
        return None
    return full_width_at(values, 0.5, start, nodes=nodes)


@dataclass(frozen=True)
class MeasuredDepthOfField:
    """Depth of field read from the lateral FWHM versus depth.

    Attributes
    ----------
    depth_of_field : float
        Summed length of the depth intervals where the FWHM stays within the criterion, m.
    depth_range : (float, float)
        Lowest and highest depth of those intervals, m.
    truncated : bool
        True when an interval reaches the first or last slice: the true depth of field
        is larger than reported (a lower bound).
    best_fwhm : float
        The smallest lateral FWHM over the stack, m.
    """

    depth_of_field: float
    depth_range: tuple[float, float]
    truncated: bool
    best_fwhm: float


def measured_depth_of_field(
    psf: PSFStack, *, criterion: float = DOF_CRITERION
) -> MeasuredDepthOfField | None:
    """Depth range over which the lateral FWHM stays within ``criterion`` x its best (see module docstring).

    Returns None when no slice has a measurable spot.
    """
    order, nodes = depth_order(psf)
    data = stack_data(psf)
    widths = []
    for i in order:
        fx, fy = spot_fwhm_pixels(data[i])
        widths.append(math.inf if fx is None or fy is None else 0.5 * (fx + fy))
    best = min(widths)
    if math.isinf(best):
        return None
    limit = criterion * best
    z = [float(v) for v in nodes]
    inside = [w <= limit for w in widths]

    def edge(k_in: int, k_out: int) -> float:
        w_in, w_out = widths[k_in], widths[k_out]
        if math.isinf(w_out) or w_out == w_in:
            return z[k_in]
        return z[k_in] + (z[k_out] - z[k_in]) * (limit - w_in) / (w_out - w_in)

    intervals, truncated, k = [], False, 0
    while k < len(z):
        if not inside[k]:
            k += 1
            continue
        first = k
        while k + 1 < len(z) and inside[k + 1]:
            k += 1
        lo = z[first] if first == 0 else edge(first, first - 1)
        hi = z[k] if k == len(z) - 1 else edge(k, k + 1)
        truncated = truncated or first == 0 or k == len(z) - 1
        intervals.append((lo, hi))
        k += 1
    total = sum(hi - lo for lo, hi in intervals)
    span = (min(lo for lo, _ in intervals), max(hi for _, hi in intervals))
    return MeasuredDepthOfField(total, span, truncated, best * psf.object_pixel_size)
