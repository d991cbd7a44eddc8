"""Two-point resolution measured on a PSF stack: the smallest separation at which two
emitters appear as two.

Two equally bright, mutually incoherent emitters image to the sum of two copies of the
PSF. Along the line joining their images the summed profile ``f`` has a maximum near
each emitter; the pair counts as **resolved** when the lowest value of ``f`` between the
two maxima is below ``threshold`` times the smaller maximum. The default threshold
0.735 is the dip of two Airy patterns at the Rayleigh distance ``0.61 lambda / NA``
(Born & Wolf, Principles of Optics, section 7.6.3), so for an aberration-free circular
pupil the result is the Rayleigh resolution; ``threshold`` close to 1 approaches the
Sparrow criterion (the dip just appears; two Gaussians of standard deviation sigma at
``2 sigma``).

- **Lateral**: the second emitter is the same spot (the brightest spot of the slice)
  shifted by ``s`` pixels along x (and, separately, y), read from the 4-point
  Lagrange interpolant of the profile through the peak (within 8 FWHM of it); ``s`` is
  scanned upward in 10 % steps from half the FWHM to the first resolved value, then bisected. Reported in the
  sample: ``s`` times the sample-side pixel size, mean of x and y.
- **Axial**: emitters at the reference depth ``z0`` and at ``z0 + dz``, for ``dz`` on the
  stack's own depths (no PSF exists between slices). For each view's spot (local
  maxima above ``min_fraction`` of the brightest) the second spot is the brightest pixel
  of the other slice near it (the same view, moved by parallax and blurred by defocus);
  the dip is read along the line joining them in the 2-D interpolated sum. The search
  box reaches 4 FWHM, but less than half-way to the next view's spot. A pair is
  resolved when any view resolves it; ``dz`` is interpolated linearly in the dip ratio
  between the last unresolved and the first resolved slice, and the smaller of the
  deeper and shallower directions is reported.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

from lfm_studio.engine.performance.interpolation import (
    full_width_at,
    lagrange_cubic,
    lagrange_cubic_2d,
    refine_peak,
    subpixel_peak,
)
from lfm_studio.engine.performance.psf_measures import depth_index, peak_pixel, spot_fwhm_pixels, stack_data
from lfm_studio.engine.psf_stack import PSFStack

RAYLEIGH_DIP = 0.735
"""Dip ratio of two Airy patterns at the Rayleigh distance (circular pupil)."""

_SAMPLES = 401  # points along the line between the two images (0.025 px steps at 10 px)
_MARGIN = 0.5  # pixels beyond each image searched for its maximum (the sum's maxima move inward)


_PROMINENCE = 1e-3
"""Local maxima less prominent than this fraction of the profile's maximum are ignored unless
they are the highest point of their half: the 4-point interpolant ripples by ~3e-4 of the peak."""


def _local_maxima(f: torch.Tensor) -> torch.Tensor:
    """Indices of the local maxima of the samples ``f`` (a plateau counts once, at its last
    sample; an end sample counts when it is above its neighbour: a maximum cut by the range)."""
    rising = torch.cat([torch.tensor([True]), f[1:] >= f[:-1]])
    falling = torch.cat([f[:-1] > f[1:], torch.tensor([True])])
    return torch.nonzero(rising & falling).flatten()


def _prominence(f: torch.Tensor, i: int) -> float:
    """Topographic prominence of the maximum ``f[i]``: its height above the higher of the lowest
    points between it and the nearest higher sample on either side (or the range's end)."""
    higher_left = torch.nonzero(f[:i] > f[i]).flatten()
    higher_right = torch.nonzero(f[i + 1 :] > f[i]).flatten()
    left = int(higher_left[-1]) + 1 if higher_left.numel() else 0
    right = i + int(higher_right[0]) if higher_right.numel() else f.numel() - 1
    return float(f[i] - max(f[left : i + 1].min(), f[i : right + 1].min()))


def dip_ratio(profile: Callable[[torch.Tensor], torch.Tensor], a: float, b: float) -> float:
    """Lowest value between the two maxima of ``profile`` nearest ``a`` and ``b``, over the smaller one.

    ``profile`` maps positions (float64 tensor) to values; ``a < b`` are the two
    emitters' image positions. The maxima are the local maxima of ``profile`` (sampled
    on ``[a - 0.5, b + 0.5]``) nearest each emitter, so a dim peak beside a bright
    peak's shoulder is found (not the shoulder). Candidates are the highest local
    maximum of each half and every local maximum at least ``_PROMINENCE`` of the
    maximum prominent (interpolation ripple is not a peak). Returns 1.0 when the same
    maximum is nearest both (a single maximum: not resolved).
    """
    if b - a <= 0.0:
        return 1.0
    t = torch.linspace(a - _MARGIN, b + _MARGIN, _SAMPLES, dtype=torch.float64)
    f = profile(t)
    maxima = _local_maxima(f).tolist()
    left = t <= 0.5 * (a + b)
    halves = {
        int(torch.argmax(torch.where(side, f, torch.full_like(f, -math.inf)))) for side in (left, ~left)
    }
    floor = _PROMINENCE * float(f.max())
    candidates = [i for i in maxima if i in halves or _prominence(f, i) >= floor]
    if not candidates:
        return 1.0
    where = t[candidates]
    i1 = candidates[int(torch.argmin((where - a).abs()))]
    i2 = candidates[int(torch.argmin((where - b).abs()))]
    i1, i2 = min(i1, i2), max(i1, i2)
    peak = min(float(f[i1]), float(f[i2]))
    if i2 - i1 < 2 or peak <= 0.0:
        return 1.0
    return float(f[i1 : i2 + 1].min()) / peak


def _first_resolved(
    ratio: Callable[[float], float], threshold: float, start: float, stop: float
) -> float | None:
    """Smallest ``s`` in ``[start, stop]`` with ``ratio(s) < threshold``: 10 % steps, then bisection."""
    lo, hi = 0.0, start
    while ratio(hi) >= threshold:
        lo, hi = hi, hi * 1.1
        if hi > stop:
            return None
    for _ in range(24):  # bracket / 2^24: far below any sampling error
        mid = 0.5 * (lo + hi)
        if ratio(mid) < threshold:
            hi = mid
        else:
            lo = mid
    return 0.5 * (lo + hi)


def _lateral_pixels(profile: torch.Tensor, index: int, threshold: float) -> float | None:
    """Smallest resolved shift (pixels) of two copies of a 1-D ``profile`` peaked at ``index``."""
    fwhm = full_width_at(profile, 0.5, index) or 2.0
    half = round(8.0 * fwhm) + 8  # the pair resolves near 1-2 FWHM: +-8 FWHM is plenty
    first = max(index - half, 0)
    values = profile.detach()[first : index + half + 1].to(torch.float64)
    x0, _ = refine_peak(values, index - first)

    def ratio(shift: float) -> float:
        return dip_ratio(
            lambda x: lagrange_cubic(values, x) + lagrange_cubic(values, x - shift), x0, x0 + shift
        )

    # No pair of one spot resolves below half its FWHM (Sparrow: 0.85 FWHM for a Gaussian, 0.92 for Airy).
    return _first_resolved(ratio, threshold, 0.5 * fwhm, min(half / 2.0, profile.numel() / 4.0))


def two_point_lateral(
    psf: PSFStack, *, depth: float | None = None, threshold: float = RAYLEIGH_DIP
) -> float | None:
    """Smallest resolved lateral separation at ``depth`` (default: best focus), sample side, m.

    Mean of the separations along x and y; None when a direction never resolves
    within a quarter of the sensor.
    """
    image = stack_data(psf)[depth_index(psf, depth)]
    row, col = peak_pixel(image)
    sx = _lateral_pixels(image[row, :], col, threshold)
    sy = _lateral_pixels(image[:, col], row, threshold)
    if sx is None or sy is None:
        return None
    return 0.5 * (sx + sy) * psf.object_pixel_size


def view_spots(image: torch.Tensor, *, radius: int, min_fraction: float) -> list[tuple[int, int]]:
    """Local maxima of ``image`` above ``min_fraction`` of its maximum, at least ``radius`` px apart."""
    img = image.to(torch.float64)[None, None]
    pooled = torch.nn.functional.max_pool2d(img, 2 * radius + 1, stride=1, padding=radius)
    candidates = ((img == pooled) & (img >= min_fraction * img.max())).nonzero()[:, 2:]
    order = torch.argsort(img[0, 0][candidates[:, 0], candidates[:, 1]], descending=True)
    spots: list[tuple[int, int]] = []
    for r, c in candidates[order].tolist():
        if all(max(abs(r - r2), abs(c - c2)) > radius for r2, c2 in spots):
            spots.append((r, c))
    return spots


def _pair_ratio(first: torch.Tensor, second: torch.Tensor, spot: tuple[int, int], window: int) -> float:
    """Dip ratio of ``first + second`` along the line from ``spot`` to the peak of ``second`` near it."""
    h, w = first.shape
    r0, r1 = max(spot[0] - window, 1), min(spot[0] + window + 1, h - 1)
    c0, c1 = max(spot[1] - window, 1), min(spot[1] + window + 1, w - 1)
    pr, pc = peak_pixel(second[r0:r1, c0:c1])
    a = subpixel_peak(first, *spot)
    b = subpixel_peak(second, r0 + pr, c0 + pc)
    length = math.hypot(b[0] - a[0], b[1] - a[1])
    if length == 0.0:
        return 1.0
    uy, ux = (b[0] - a[0]) / length, (b[1] - a[1]) / length
    pad = window + 4  # interpolate on a local patch, not the whole sensor
    top, left = max(spot[0] - pad, 0), max(spot[1] - pad, 0)
    rows, cols = slice(top, spot[0] + pad + 1), slice(left, spot[1] + pad + 1)
    patch = first[rows, cols] + second[rows, cols]
    if min(patch.shape) < 4:
        return 1.0

    def profile(t: torch.Tensor) -> torch.Tensor:
        return lagrange_cubic_2d(patch, a[0] - top + t * uy, a[1] - left + t * ux)

    return dip_ratio(profile, 0.0, length)


def two_point_axial(
    psf: PSFStack,
    *,
    depth: float | None = None,
    threshold: float = RAYLEIGH_DIP,
    min_fraction: float = 0.25,
) -> float | None:
    """Smallest resolved axial separation from ``depth`` (default: best focus), m (see module docstring).

    None when no slice of the stack resolves the pair in either direction.
    """
    data = stack_data(psf)
    k0 = depth_index(psf, depth)
    first = data[k0].to(torch.float64)
    fx, fy = spot_fwhm_pixels(first)
    fwhm = max(fx or 2.0, fy or 2.0)
    spots = view_spots(first, radius=max(2, round(fwhm)), min_fraction=min_fraction)
    # Search the moved spot within 4 FWHM, but never as far as half-way to another view's spot.
    gaps = [max(abs(a[0] - b[0]), abs(a[1] - b[1])) for i, a in enumerate(spots) for b in spots[i + 1 :]]
    window = max(2, min([round(4.0 * fwhm), *(g // 2 - 1 for g in gaps)]))
    z0 = psf.depths[k0]
    found = []
    for sign in (1.0, -1.0):
        steps = sorted((k for k in range(len(psf.depths)) if (psf.depths[k] - z0) * sign > 0),
                       key=lambda k: abs(psf.depths[k] - z0))  # fmt: skip
        last_dz, last_ratio = 0.0, 1.0
        for k in steps:
            second = data[k].to(torch.float64)
            ratio = min((_pair_ratio(first, second, spot, window) for spot in spots), default=1.0)
            dz = abs(psf.depths[k] - z0)
            if ratio < threshold:
                found.append(last_dz + (dz - last_dz) * (last_ratio - threshold) / (last_ratio - ratio))
                break
            last_dz, last_ratio = dz, ratio
    return min(found) if found else None
