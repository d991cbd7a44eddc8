"""Where each lenslet's light lands on the sensor, and the small grid that computes it.

For lenslet ``i`` (centre ``c``, aperture half-width ``a``, focal length ``f``) at
distance ``d`` from the sensor, a ray leaving the aperture at ``r`` with slope ``s(r)``
lands at ``u - c = (r - c)(1 - d/f) + d s(r)``; over the depths that bounds the
footprint radius by ``a |1 - d/f| + d max|s|``. A diffraction margin of
``margin_airy * lambda d / D`` is added: the Airy pattern keeps about
``2 / (pi^2 margin_airy)`` of its power beyond that radius (0.6 % at 32).

The lenslet is then computed with one single-FFT Fresnel transform (thesis eq. 3.12)
on ``N x N`` samples: output spacing ``p / s`` (``s`` sub-samples per sensor pixel per
axis) needs an input spacing ``lambda d s / (N p)``; the output window of ``N p / s``
covers the footprint. ``N`` is a multiple of ``s`` and the window starts on a pixel
edge, so ``s x s`` binning is the exact area integral over each pixel.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lfm_studio.engine.memory import require_memory, tensor_bytes
from lfm_studio.engine.operators.fft_sizes import next_fast_length
from lfm_studio.engine.optics.mla_layout import Lenslet
from lfm_studio.engine.optics.objective import _value
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem


def rim_radius(lens: Lenslet) -> float:
    """Largest distance from a lenslet's centre to its aperture edge, metres."""
    half = lens.aperture_diameter / 2.0
    return half * math.sqrt(2.0) if lens.shape == "square" else half


@dataclass(frozen=True)
class LensletWindow:
    """The small grid of one lenslet and where its result goes on the sensor.

    Attributes
    ----------
    samples : N, samples per side of the input patch and of the output window.
    input_spacing : MLA-plane sample spacing of the patch, metres.
    first_pixel : (row, col) sensor pixel of the window's top-left corner (may lie off the sensor).
    shift : (dy, dx) offset of output sample ``N // 2`` from the lenslet centre, metres.
    footprint_radius : geometric + diffraction radius of the light on the sensor, metres.
    """

    samples: int
    input_spacing: float
    first_pixel: tuple[int, int]
    shift: tuple[float, float]
    footprint_radius: float

    def pixels(self, oversampling: int) -> int:
        """Sensor pixels per side of the window."""
        return self.samples // oversampling


def footprint_radius(
    system: FourierLFMSystem, lens: Lenslet, depths: tuple[float, ...], margin_airy: float
) -> float:
    """Radius (m) around the lenslet centre that holds its light on the sensor for ``depths``."""
    d = system.mla_to_camera
    a = rim_radius(lens)
    f = float(_value(lens.focal_length))
    reach = math.hypot(*lens.center) + a
    slope = max(system.max_slope(z, reach) for z in depths)
    geometric = a * abs(1.0 - d / f) + d * slope
    diffraction = margin_airy * system.wavelength * d / lens.aperture_diameter
    return geometric + diffraction


def _axis_placement(
    center: float, samples: int, oversampling: int, pitch: float, sensor: int
) -> tuple[int, float]:
    """First pixel index and output shift along one axis (see module docstring)."""
    step = pitch / oversampling
    # Output sample k sits at center + (k - N//2) step + shift and must be the centre of
    # sub-sample k of pixel first + k // s: (first - P//2) p - p/2 + (k + 1/2) step.
    first = round((center + pitch / 2.0 - (samples // 2 + 0.5) * step) / pitch) + sensor // 2
    shift = (first - sensor // 2) * pitch - pitch / 2.0 + (samples // 2 + 0.5) * step - center
    return first, shift


def plan_window(
    system: FourierLFMSystem,
    lens: Lenslet,
    depths: tuple[float, ...],
    *,
    oversampling: int,
    margin_airy: float,
) -> LensletWindow:
    """Choose ``N``, the input spacing and the sensor placement for one lenslet."""
    radius = footprint_radius(system, lens, depths, margin_airy)
    where = f"the lenslet at ({lens.center[0] * 1e6:.4g}, {lens.center[1] * 1e6:.4g}) um"
    deepest = max((abs(z) for z in depths), default=0.0)
    if not math.isfinite(radius):
        raise ValueError(
            f"the light footprint of {where} is not finite for depths {tuple(depths)} m. "
            "Fix: give finite depths in metres, e.g. (-10e-6, 0.0, 10e-6)."
        )
    p, s = system.pixel_pitch, oversampling
    # The window must hold the footprint wherever the sub-pixel shift (<= p/2) puts it.
    pixels = math.ceil((2.0 * radius + system.pixel_pitch) / p) + 1
    samples = fast_samples(  # even: see fourier_lenslet
        pixels,
        s,
        what=f"the window of {where}, for a light footprint of radius {radius:.3g} m on the sensor at "
        f"depths up to {deepest:.3g} m",
        fix="give depths in metres (10 um is 10e-6) near the design's depth range: a footprint this "
        "wide means a source far out of focus.",
    )
    spacing = system.wavelength * system.mla_to_camera * s / (samples * p)
    patch = samples * spacing
    if patch < 2.0 * rim_radius(lens):
        needed = math.ceil(2.0 * rim_radius(lens) * p / (system.wavelength * system.mla_to_camera))
        raise ValueError(
            f"oversampling {s} is too small for lenslet at {lens.center} m: the input patch "
            f"({patch * 1e6:.4g} um) cannot hold its aperture ({2e6 * rim_radius(lens):.4g} um). "
            f"Fix: use oversampling >= {needed}."
        )
    (ry, cy) = _axis_placement(lens.center[1], samples, s, p, system.sensor_shape[0])
    (rx, cx) = _axis_placement(lens.center[0], samples, s, p, system.sensor_shape[1])
    return LensletWindow(samples, spacing, (ry, rx), (cy, cx), radius)


def fast_samples(
    pixels: int,
    oversampling: int,
    *,
    what: str = "a lenslet window",
    fix: str = "lower accuracy.oversampling or accuracy.margin_airy.",
) -> int:
    """Samples per side for ``pixels`` whole pixels or more: a multiple of ``oversampling``, even
    (see :mod:`fourier_lenslet`) and a fast FFT length.

    A window whose ``pixels * oversampling`` squared complex samples cannot fit in memory is
    refused first (:class:`~lfm_studio.engine.memory.MemoryBudgetError` naming ``what`` and
    ``fix``), as is an ``oversampling`` with a prime factor above 5 (no multiple of it is a
    fast length).
    """
    step = math.lcm(2, oversampling)  # samples are the multiples of step that are fast lengths
    if next_fast_length(step) != step:
        raise ValueError(
            f"oversampling must have no prime factor above 5; got {oversampling} (no multiple of it is "
            "a 2-3-5-smooth FFT length). Fix: use 2 or 3."
        )
    wanted = pixels * oversampling
    require_memory(
        tensor_bytes((wanted, wanted), torch.complex64), f"{what} ({wanted} x {wanted} samples)", fix
    )
    # step is 2-3-5-smooth, so step * k is a fast length exactly when k is.
    return step * next_fast_length(-(-wanted // step))


def shared_window(
    system: FourierLFMSystem,
    lens: Lenslet,
    window: LensletWindow,
    first_pixel: tuple[int, int],
    samples: int,
    *,
    oversampling: int,
) -> LensletWindow:
    """``window`` moved onto a canvas of ``samples`` per side starting at ``first_pixel``: the
    same sensor sub-pixel grid for every lenslet of a group, so their fields add sample by sample.

    The input patch keeps its width ``lambda d s / p`` (only its sampling changes), so it holds
    the aperture whenever ``window`` does.
    """
    p, s = system.pixel_pitch, oversampling
    step = p / s
    ny, nx = system.sensor_shape

    def shift(center: float, first: int, sensor: int) -> float:  # as in _axis_placement
        return (first - sensor // 2) * p - p / 2.0 + (samples // 2 + 0.5) * step - center

    spacing = system.wavelength * system.mla_to_camera * s / (samples * p)
    return LensletWindow(
        samples,
        spacing,
        first_pixel,
        (shift(lens.center[1], first_pixel[0], ny), shift(lens.center[0], first_pixel[1], nx)),
        window.footprint_radius,
    )


def windows_overlap(
    a: LensletWindow, b: LensletWindow, ca: tuple[float, float], cb: tuple[float, float]
) -> bool:
    """True when the light footprints (discs) of two lenslets overlap on the sensor."""
    return math.hypot(ca[0] - cb[0], ca[1] - cb[1]) < a.footprint_radius + b.footprint_radius
