"""Bead-measured PSF stacks prepared for reconstruction, interchangeable with simulated ones.

A bead z-scan (one sub-resolution bead imaged at each depth of a list) is loaded with
:func:`~lfm_studio.engine.io.read_psf_stack` (depths, pixel size, magnification and
wavelength from the file, or given as keywords when a foreign TIFF lacks them), then :func:`prepare_measured_psf` turns the
camera frames into a :class:`~lfm_studio.engine.psf_stack.PSFStack` a projector can
use exactly like a simulated one. The steps, in order (in the stack's dtype, sums and
centroids in float64):

1. **Background** per depth slice: ``"border"`` (default) is a sigma-clipped mean of
   a frame ``border`` pixels wide around the slice (median and 1.4826 x MAD to start,
   then three rounds of mean and standard deviation of the pixels within 3 sigmas:
   robust to a sub-image that touches the edge, unbiased for Poisson/Gaussian noise); ``"percentile"`` is the
   ``percentile``-th percentile of the slice (50: the slice median, fine for sparse
   PSFs); a number is a constant in the file's units.
2. **Noise floor**: after subtraction, values below ``threshold`` robust sigmas of the
   border noise are set to 0 (negatives always are). Plain clipping keeps the positive
   half of the noise, about ``0.4 sigma`` per pixel, which over a whole sensor adds up
   to a large false energy; a 3-sigma floor leaves ``< 0.01 sigma`` per pixel.
3. **Centring**: the bead centroid (intensity-weighted, of the depth-summed cleaned
   stack, so ONE lateral shift for all depths: per-depth centring would erase the
   parallax that encodes depth in a light-field PSF; refined in a window symmetric
   about it, so light cut off by one frame edge does not bias it; exact for a
   point-symmetric PSF such as a symmetric lenslet layout's) is moved to the sensor centre,
   pixel ``(ny // 2, nx // 2)`` (the :class:`~lfm_studio.engine.optics.grid.Grid`
   convention); whole pixels by zero-filled translation, the sub-pixel remainder by a
   Fourier shift (``subpixel=True``), negatives of its ringing clipped.
4. **Resampling** to the image's pixel pitch when it differs from the stack's:
   area-weighted integration of the frames over the new pixels
   (:func:`~lfm_studio.engine.optics.camera.integrate_pixels`, values taken constant
   over each measured pixel; energy-conserving). The magnification is unchanged, so the
   sample-side pixel becomes ``pixel_size / magnification``.
5. **Cropping / padding** to ``sensor_shape`` (centred, zero-padded where larger).
6. **Normalisation**: ``"stack"`` (default) scales the whole stack by one factor so the
   mean per-depth sum is ``energy``; ``"per_depth"`` scales every depth to ``energy``;
   ``"none"`` keeps the file's units.

Why Richardson-Lucy needs the normalisation: RL fits ``A x + b`` to the image, so a
PSF scaled by ``c`` gives a volume scaled by ``1/c`` (volume values are "image counts
per unit PSF energy"); to compare with a simulated-PSF reconstruction or a ground
truth, both PSFs must carry the same energy (pass the simulated stack's mean
per-depth sum as ``energy``; the default 1 makes a voxel value the counts its
emitters put on the camera). A per-depth scale error ``c_z`` (bead bleaching during
the scan, lamp drift) is not absorbed by the fit: it divides depth ``z`` of every
reconstruction by ``c_z``. ``"stack"`` keeps the measured change of collected energy
with depth (sub-images leaving the sensor, apertures); use ``"per_depth"`` when the bead
bleached during the scan.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Literal

import torch

from lfm_studio.engine import fft
from lfm_studio.engine.optics.camera import integrate_pixels
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.types import JSONValue

Background = Literal["border", "percentile"] | float
Normalize = Literal["stack", "per_depth", "none"]
_MAD_TO_SIGMA = 1.4826  # standard deviation of Gaussian noise from its median absolute deviation
_CLIP_SIGMAS = 3.0  # sigma-clipping of the border pixels
_CLIP_ROUNDS = 3
_CLIPPED_STD = 0.9866  # standard deviation of a unit normal truncated at +-3 (undoes the clipping bias)


def _border_pixels(slices: torch.Tensor, width: int) -> torch.Tensor:
    """``(Z, K)`` pixels of a frame ``width`` wide around each slice of ``(Z, Y, X)``."""
    mask = torch.ones(slices.shape[-2:], dtype=torch.bool, device=slices.device)
    mask[width:-width, width:-width] = False
    return slices[:, mask]


def estimate_background(
    slices: torch.Tensor, method: Background = "border", *, border: int = 8, percentile: float = 50.0
) -> tuple[torch.Tensor, torch.Tensor]:
    """Background level and robust noise sigma per depth, both ``(Z,)`` float64, in data units.

    ``method``: ``"border"`` (sigma-clipped mean of the frame ``border`` px wide),
    ``"percentile"`` (that percentile of the whole slice), or a number. The noise sigma
    is always the sigma-clipped standard deviation of the border frame.
    """
    z, ny, nx = slices.shape
    if not (isinstance(border, int) and border >= 1 and 2 * border < min(ny, nx)):
        raise ValueError(
            f"border must be a whole number of pixels with 1 <= border < {min(ny, nx) / 2:g} for slices of "
            f"{ny} x {nx} px; got {border!r}. Fix: use a smaller border, e.g. 8."
        )
    edge = _border_pixels(slices, border).double()
    level = edge.median(dim=1).values
    sigma = _MAD_TO_SIGMA * (edge - level[:, None]).abs().median(dim=1).values
    for _ in range(_CLIP_ROUNDS):  # sigma clipping: drop light that reaches the border, then re-estimate
        keep = (edge - level[:, None]).abs() <= _CLIP_SIGMAS * sigma[:, None]
        count = keep.sum(dim=1).clamp_min(2)
        level = (edge * keep).sum(dim=1) / count
        spread = (((edge - level[:, None]) * keep) ** 2).sum(dim=1) / (count - 1)
        sigma = spread.sqrt() / _CLIPPED_STD
    if isinstance(method, (int, float)) and not isinstance(method, bool):
        if not math.isfinite(method):
            raise ValueError(f"background must be finite (data units); got {method!r}.")
        return torch.full((z,), float(method), dtype=torch.float64, device=slices.device), sigma
    if method == "border":
        return level, sigma
    if method == "percentile":
        if not 0 <= percentile <= 100:
            raise ValueError(f"percentile must be in [0, 100]; got {percentile!r}.")
        return torch.quantile(slices.reshape(z, -1), percentile / 100.0, dim=1).double(), sigma
    raise ValueError(f"background must be 'border', 'percentile' or a number; got {method!r}.")


def _centroid(image: torch.Tensor) -> tuple[float, float]:
    total = image.sum()
    y = torch.arange(image.shape[0], dtype=image.dtype, device=image.device)
    x = torch.arange(image.shape[1], dtype=image.dtype, device=image.device)
    return float((image.sum(dim=1) * y).sum() / total), float((image.sum(dim=0) * x).sum() / total)


def bead_centroid(data: torch.Tensor, *, iterations: int = 20) -> tuple[float, float]:
    """Bead position ``(y, x)`` in pixel indices of a cleaned ``(Z, Y, X)`` stack (summed over depth).

    The intensity-weighted centroid, refined inside the largest window symmetric about the
    current estimate that fits in the frame (repeated until it moves < 0.001 px): light cut
    off by the frame edge on one side would otherwise pull the centroid away from it.
    """
    image = data.sum(dim=0, dtype=torch.float64)
    if not float(image.sum()) > 0:
        raise ValueError(
            "The measured PSF has no signal left after background subtraction (all pixels at or below the "
            "noise floor). Fix: check the file, lower threshold, or give background explicitly."
        )
    centre = _centroid(image)
    for _ in range(iterations):
        index = [min(max(round(c), 0), n - 1) for c, n in zip(centre, image.shape, strict=True)]
        half = [min(i, n - 1 - i) for i, n in zip(index, image.shape, strict=True)]
        part = image[index[0] - half[0] : index[0] + half[0] + 1, index[1] - half[1] : index[1] + half[1] + 1]
        if not float(part.sum()) > 0:
            break
        local = _centroid(part)
        moved = (index[0] - half[0] + local[0], index[1] - half[1] + local[1])
        done = max(abs(moved[0] - centre[0]), abs(moved[1] - centre[1])) < 1e-3
        centre = moved
        if done:
            break
    return centre


def _window(data: torch.Tensor, centre: tuple[int, int], shape: tuple[int, int]) -> torch.Tensor:
    """The ``shape`` window of ``(Z, Y, X)`` whose centre pixel ``(n // 2)`` is ``centre``; zeros outside."""
    out = data.new_zeros((data.shape[0], *shape))
    src, dst = [], []
    for c, n, size in zip(centre, shape, data.shape[-2:], strict=True):
        start = c - n // 2
        lo, hi = max(0, start), min(size, start + n)
        if hi <= lo:
            return out
        src.append(slice(lo, hi))
        dst.append(slice(lo - start, hi - start))
    out[:, dst[0], dst[1]] = data[:, src[0], src[1]]
    return out


def fourier_shift(data: torch.Tensor, shift: tuple[float, float]) -> torch.Tensor:
    """Translate real ``(..., Y, X)`` frames by ``shift = (dy, dx)`` pixels (periodic, band-limited)."""
    ny, nx = data.shape[-2:]
    fy = torch.fft.fftfreq(ny, dtype=torch.float64, device=data.device)[:, None]
    fx = torch.fft.rfftfreq(nx, dtype=torch.float64, device=data.device)[None, :]
    phase = -2 * math.pi * (fy * shift[0] + fx * shift[1])  # float64, cast only the exponential
    spectrum = fft.rfft2(data)
    ramp = torch.polar(torch.ones_like(phase), phase).to(spectrum.dtype)
    return fft.irfft2(spectrum * ramp, s=(ny, nx))


def _centred(
    work: torch.Tensor, centre: bool | tuple[float, float], subpixel: bool
) -> tuple[torch.Tensor, tuple[float, float] | None, tuple[float, float]]:
    """Frames with the bead moved to pixel ``(ny // 2, nx // 2)`` (grown so nothing is cut), the
    centroid used and the shift applied (pixels)."""
    if centre is False:
        return work, None, (0.0, 0.0)
    centroid = bead_centroid(work) if centre is True else (float(centre[0]), float(centre[1]))
    ny, nx = work.shape[-2:]
    shift = (ny // 2 - centroid[0], nx // 2 - centroid[1])
    whole = (round(shift[0]), round(shift[1]))
    grown = (ny + 2 * abs(whole[0]), nx + 2 * abs(whole[1]))  # cropping happens at the end
    work = _window(work, (ny // 2 - whole[0], nx // 2 - whole[1]), grown)
    if not subpixel:
        return work, centroid, (float(whole[0]), float(whole[1]))
    rest = (shift[0] - whole[0], shift[1] - whole[1])
    if rest[0] or rest[1]:
        work = fourier_shift(work, rest).clamp_min(0.0)  # ringing below 0 is not light
    return work, centroid, shift


def _resampled(
    work: torch.Tensor,
    source_pitch: float,
    target_pitch: float,
    sensor_shape: tuple[int, int] | None,
    source_shape: tuple[int, int],
) -> torch.Tensor:
    """Frames on ``sensor_shape`` pixels of ``target_pitch`` metres, centred (area-weighted when the pitch changes)."""
    same_pitch = math.isclose(target_pitch, source_pitch, rel_tol=1e-9)
    if sensor_shape is None:
        ratio = source_pitch / target_pitch
        sy, sx = source_shape
        sensor_shape = source_shape if same_pitch else (max(1, round(sy * ratio)), max(1, round(sx * ratio)))
    if len(sensor_shape) != 2 or any(int(n) != n or n < 1 for n in sensor_shape):
        raise ValueError(f"sensor_shape must be (ny, nx) positive integers; got {sensor_shape!r}.")
    sensor_shape = (int(sensor_shape[0]), int(sensor_shape[1]))
    if same_pitch:
        ny, nx = work.shape[-2:]
        return _window(work, (ny // 2, nx // 2), sensor_shape)
    grid = Grid((work.shape[-2], work.shape[-1]), source_pitch)
    return integrate_pixels(work / grid.pixel_area, grid, target_pitch, shape=sensor_shape)


def _normalised(
    work: torch.Tensor, normalize: Normalize, energy: float
) -> tuple[torch.Tensor, torch.Tensor, float | None]:
    """Frames scaled as ``normalize`` says, their float64 sums before scaling, and the global scale."""
    sums = work.sum(dim=(1, 2), dtype=torch.float64)
    if normalize == "none":
        return work, sums, 1.0
    if normalize == "stack":
        mean = float(sums.mean())
        return (work * (energy / mean), sums, energy / mean) if mean > 0 else (work, sums, 1.0)
    if bool((sums <= 0).any()):
        empty = [i for i, total in enumerate(sums.tolist()) if total <= 0]
        raise ValueError(
            f"normalize='per_depth': depth slice(s) {empty} have no signal after background subtraction. "
            "Fix: use normalize='stack', or drop those depths."
        )
    return work * (energy / sums).to(work.dtype)[:, None, None], sums, None


def prepare_measured_psf(
    stack: PSFStack,
    *,
    sensor_shape: tuple[int, int] | None = None,
    pixel_size: float | None = None,
    background: Background = "border",
    border: int = 8,
    percentile: float = 50.0,
    threshold: float = 3.0,
    centre: bool | tuple[float, float] = True,
    subpixel: bool = True,
    normalize: Normalize = "stack",
    energy: float = 1.0,
) -> PSFStack:
    """A bead-measured PSF stack cleaned, centred, resampled and normalised (module docstring).

    Parameters
    ----------
    stack : PSFStack with data ``(Z, Y, X)`` in camera units (counts), as read from the TIFF.
    sensor_shape : (ny, nx) pixels of the result (the image's shape); default the
        measured field of view at the new pitch.
    pixel_size : sensor pixel pitch of the result in metres (the image's); default the stack's.
    background : "border" | "percentile" | number (data units); see :func:`estimate_background`.
    border : width in pixels of the border frame used for the background and the noise sigma.
    percentile : for ``background="percentile"``.
    threshold : noise floor in robust noise sigmas (0: only clip negatives).
    centre : True to move the bead centroid to the sensor centre; False to keep the
        frames where they are; or the bead position ``(y, x)`` in pixel indices.
    subpixel : apply the sub-pixel remainder of the centring by a Fourier shift.
    normalize : "stack" | "per_depth" | "none"; ``energy`` is the target mean (or
        per-depth) sum.

    Returns
    -------
    PSFStack (``design=None`` unless the file carried one) whose ``metadata["measured"]``
    records what was done: background per depth, noise sigma, centroid and shift (pixels),
    source pitch, per-depth energy before normalisation and the scale applied.
    """
    data = stack.data.detach()
    if data.ndim != 3:
        raise ValueError(
            f"prepare_measured_psf needs a bead stack (Z, Y, X); got shape {tuple(data.shape)}. "
            "Conventional-LFM pattern stacks are shift-variant and cannot be measured with one bead."
        )
    if normalize not in ("stack", "per_depth", "none"):
        raise ValueError(f"normalize must be 'stack', 'per_depth' or 'none'; got {normalize!r}.")
    if not (math.isfinite(energy) and energy > 0):
        raise ValueError(f"energy must be a finite number > 0 (sum of a PSF slice); got {energy!r}.")
    if not (math.isfinite(threshold) and threshold >= 0):
        raise ValueError(f"threshold must be >= 0 (robust noise sigmas); got {threshold!r}.")
    target_pitch = stack.pixel_size if pixel_size is None else float(pixel_size)
    if not (math.isfinite(target_pitch) and target_pitch > 0):
        raise ValueError(f"pixel_size must be a finite number > 0 m; got {pixel_size!r}.")
    level, sigma = estimate_background(data, background, border=border, percentile=percentile)
    work = data - level.to(data.dtype)[:, None, None]
    floor = (threshold * sigma).to(data.dtype)[:, None, None]
    work = torch.where(work > floor, work, torch.zeros_like(work))

    work, centroid, shift = _centred(work, centre, subpixel)
    work = _resampled(work, stack.pixel_size, target_pitch, sensor_shape, (data.shape[-2], data.shape[-1]))
    work, sums, scale = _normalised(work, normalize, energy)
    if not float(work.sum()) > 0:
        bead_centroid(work)  # raises the named "no signal" error
    record: dict[str, JSONValue] = {
        "background": level.tolist(),
        "noise_sigma": sigma.tolist(),
        "threshold_sigmas": threshold,
        "centroid_px": list(centroid) if centroid is not None else None,
        "shift_px": list(shift),
        "source_pixel_size_um": stack.pixel_size * 1e6,
        "source_shape": list(data.shape),
        "depth_energy": (sums / sums.mean()).tolist() if float(sums.mean()) > 0 else None,
        "normalize": normalize,
        "energy": energy,
        "scale": scale,
    }
    return replace(
        stack,
        data=work.to(dtype=data.dtype),
        pixel_size=target_pitch,
        metadata={**stack.metadata, "measured": record},
    )
