"""What a viewer layer shows: float32 data in micrometres, its look, and a max-pooled pyramid.

Pure numpy/torch (no Qt): the studio builds these on its worker threads, so the GUI
thread only hands finished arrays to the canvas (building one for a 64 x 2048 x 2048 PSF
stack reads 1 GiB: its range and pyramid take about a second).

Display conventions (also written into each layer's ``metadata``):

- PSF stacks and light-field images are in **sensor** micrometres: lateral pixel = the camera
  pixel pitch (camera side; the sample-side size is pitch / magnification), the optical axis
  at pixel ``N // 2``. The PSF's depth axis is the source depth in sample-side micrometres.
- Reconstructions are in **sample** micrometres (voxel size as given), centred on the
  optical axis unless an origin is given.
- A PSF spans millimetres on the sensor but only tens of micrometres in depth, so a
  display-only axial stretch (``z_stretch``, a 1-2-5 number) is applied through the layer's
  affine when the depth span is small; ``layer.scale`` stays the physical scale in um.
- Large data also carries ``levels``: copies max-pooled 2 x 2 laterally per level (a
  multiscale pyramid). A canvas showing a 2048-pixel sensor in 700 screen pixels draws
  from a pooled level, so a PSF spot a few pixels wide stays visible (subsampling the
  full image dropped most of them); the coarsest level, at most ``max_voxels_3d`` per 3-D
  block, is what 3-D rendering uses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.kinds import stack_kind

#: Per displayed 3-D block: 2**24 float32 voxels = 64 MiB, about 0.45 s/frame in software GL.
DEFAULT_MAX_VOXELS_3D = 2**24
#: Display gamma of PSF stacks: a Fourier-LFM PSF is a few bright spots with faint side lobes
#: in a black sensor frame; gamma 0.5 with 0.1-99.9 % limits shows both (linear showed single pixels).
PSF_GAMMA = 0.5
#: Display gamma of volumes: lifts a bead's blur around its peak voxel, so a bead reads as a spot.
VOLUME_GAMMA = 0.5
#: Percentile (%) of a volume's non-zero voxels used as its upper contrast limit (:func:`volume_limits`).
VOLUME_PERCENTILE = 99.99
#: Percentiles (%) of the robust contrast limits of PSFs and camera images.
ROBUST_PERCENTILES = (0.1, 99.9)
#: Samples drawn (fixed seed) to estimate the percentiles of large data.
PERCENTILE_SAMPLES = 2_000_000
SENSOR, SAMPLE = "sensor", "sample"


@dataclass
class DisplayData:
    """One layer as shown: float32 data ``(..., Y, X)``, sampling in um, look and provenance."""

    name: str
    data: np.ndarray
    scale_um: tuple[float, ...]
    translate_um: tuple[float, ...]
    space: str
    axis_labels: tuple[str, ...]
    colormap: str
    contrast_limits: tuple[float, float] | None  # None: per-slice auto contrast
    gamma: float = 1.0  # display gamma (< 1 lifts faint structure: sparse PSFs)
    z_stretch: float = 1.0  # display-only axial exaggeration (through the layer affine)
    has_depth: bool = True  # the third-last axis is depth
    initial_step: dict[int, int] = field(default_factory=dict)  # starting slider positions
    metadata: dict[str, Any] = field(default_factory=dict)
    levels: tuple[np.ndarray, ...] = ()  # max-pooled pyramid below ``data`` (2x per level), coarse last
    data_range: tuple[float, float] = (0.0, 1.0)  # (min, max) of ``data``

    @property
    def pyramid(self) -> list[np.ndarray]:
        """``[data, *levels]``: full resolution first."""
        return [self.data, *self.levels]

    def level_factor(self, level: int) -> int:
        """Lateral pooling factor of pyramid level ``level`` (0 = full data)."""
        return round(self.data.shape[-1] / self.pyramid[level].shape[-1]) if level else 1

    @property
    def z_axis(self) -> int | None:
        """Index of the depth axis in ``data`` (``None`` for 2-D images)."""
        return self.data.ndim - 3 if self.has_depth else None


def rectified_note(stack: PSFStack) -> str | None:
    """How a conventional stack's sensor differs from the design's camera: its pixels are resampled to
    a whole number per lenslet (e.g. 6.5 µm -> 6.579 µm, 19 per lenslet); None when they are the camera's."""
    if stack.patterns is None:
        return None
    design = stack.design
    camera = design.get("camera") if isinstance(design, dict) else getattr(design, "camera", None)
    pitch = (
        camera.get("pixel_pitch_um") if isinstance(camera, dict) else getattr(camera, "pixel_pitch_um", None)
    )
    per_lenslet = stack.patterns.pixels_per_lenslet
    if pitch is None or math.isclose(pitch, stack.pixel_size * 1e6, rel_tol=1e-9):
        return None
    return f"resampled from the camera's {pitch:g} µm pixels to {per_lenslet} whole pixels per lenslet"


def psf_display(
    stack: PSFStack, name: str = "PSF", *, max_voxels_3d: int = DEFAULT_MAX_VOXELS_3D
) -> DisplayData:
    """A PSF stack (Fourier ``(Z, Y, X)`` or conventional ``(S, S, Z, H, H)``) for display."""
    data = _numpy(stack.data)
    depths = np.asarray(stack.depths, dtype=np.float64) * 1e6
    order = np.argsort(depths)
    if np.any(order != np.arange(depths.size)):
        data, depths = np.take(data, order, axis=-3), depths[order]
    dz, uniform = _depth_step(depths, stack.object_pixel_size * 1e6)
    px = stack.pixel_size * 1e6
    ny, nx = data.shape[-2:]
    lead = data.ndim - 3
    kind = stack_kind(stack)
    patterns = len(kind.pattern_axes) == lead > 0  # lenslet patterns: step through the sub-positions
    lead_labels = kind.pattern_axes if patterns else _axis_names(lead)
    z_span = dz * depths.size
    meta = {
        "kind": "psf",
        "model": kind.name,
        "space": SENSOR,
        "units": "um",
        "lateral": "sensor pixel pitch (camera side); sample side = pitch / magnification",
        "pixel_size_um": px,
        "sample_pixel_size_um": stack.object_pixel_size * 1e6,
        "magnification": stack.magnification,
        "wavelength_nm": stack.wavelength * 1e9,
        "depth": "source depth, sample side, relative to the native focal plane",
        "depths_um": [float(z) for z in depths],
        "uniform_depths": uniform,
        "source_shape": tuple(stack.data.shape),
        "note": rectified_note(stack),
    }
    shown = DisplayData(
        name=name,
        data=data,
        scale_um=(1.0,) * lead + (dz, px, px),
        translate_um=(0.0,) * lead + (float(depths[0]), -(ny // 2) * px, -(nx // 2) * px),
        space=SENSOR,
        axis_labels=(*lead_labels, "z", "y", "x"),
        colormap="magma",
        contrast_limits=_robust_limits(data, floor=0.0),
        gamma=PSF_GAMMA,
        z_stretch=_z_stretch(z_span, min(ny, nx) * px),
        initial_step={axis: data.shape[axis] // 2 for axis in range(lead)} if patterns else {},
        metadata=meta,
    )
    return _finish(shown, max_voxels_3d)


def image_display(
    image: torch.Tensor,
    pixel_size_m: float,
    name: str = "light field",
    *,
    max_voxels_3d: int = DEFAULT_MAX_VOXELS_3D,
    note: str | None = None,
) -> DisplayData:
    """A camera image ``(..., Y, X)`` with square pixels of ``pixel_size_m`` metres (``note``: how
    they came about, e.g. :func:`rectified_note`, appended to the info line)."""
    pixel_size_m = _require_size("pixel_size_m", pixel_size_m)
    data = _numpy(image)
    if data.ndim < 2:
        raise ValueError(f"image must have shape (..., Y, X); got shape {data.shape}.")
    px = pixel_size_m * 1e6
    ny, nx = data.shape[-2:]
    lead = data.ndim - 2
    meta = {
        "kind": "image", "space": SENSOR, "units": "um", "pixel_size_um": px, "lateral": "sensor pixels",
        "note": note,
    }  # fmt: skip
    shown = DisplayData(
        name=name,
        data=data,
        scale_um=(1.0,) * lead + (px, px),
        translate_um=(0.0,) * lead + (-(ny // 2) * px, -(nx // 2) * px),
        space=SENSOR,
        axis_labels=(*_axis_names(lead), "y", "x"),
        colormap="gray",
        contrast_limits=_robust_limits(data),
        has_depth=False,
        metadata=meta,
    )
    return _finish(shown, max_voxels_3d)


def volume_display(
    volume: torch.Tensor,
    voxel_size_m: tuple[float, float, float],
    name: str = "reconstruction",
    origin_m: tuple[float, float, float] | None = None,
    *,
    max_voxels_3d: int = DEFAULT_MAX_VOXELS_3D,
) -> DisplayData:
    """A sample volume ``(..., Z, Y, X)``; voxel ``(dz, dy, dx)`` and origin (voxel 0) in metres."""
    data = _numpy(volume)
    if data.ndim < 3 or len(voxel_size_m) != 3:
        raise ValueError(
            f"volume must be (..., Z, Y, X) with voxel_size_m (dz, dy, dx); got shape {data.shape}, "
            f"voxel_size_m {voxel_size_m!r}."
        )
    scale = tuple(
        _require_size(f"voxel_size_m[{a}]", s) * 1e6 for a, s in zip("zyx", voxel_size_m, strict=True)
    )
    if origin_m is None:  # centred on the optical axis and the native focal plane
        origin = tuple(-(n // 2) * s for n, s in zip(data.shape[-3:], scale, strict=True))
    else:
        origin = tuple(o * 1e6 for o in origin_m)
    lead = data.ndim - 3
    z_span, lateral = scale[0] * data.shape[-3], min(data.shape[-2] * scale[1], data.shape[-1] * scale[2])
    meta = {
        "kind": "volume",
        "space": SAMPLE,
        "units": "um",
        "voxel_size_um": scale,
        "lateral": "sample side",
    }
    shown = DisplayData(
        name=name,
        data=data,
        scale_um=(1.0,) * lead + scale,
        translate_um=(0.0,) * lead + origin,
        space=SAMPLE,
        axis_labels=(*_axis_names(lead), "z", "y", "x"),
        colormap="inferno",
        contrast_limits=None,  # below, from the data
        gamma=VOLUME_GAMMA,
        z_stretch=_z_stretch(z_span, lateral),
        initial_step={lead: brightest_slice(data)},  # sparse volumes: z = 0 is often empty
        metadata=meta,
    )
    _finish(shown, max_voxels_3d)
    shown.contrast_limits = volume_limits(data, shown.data_range)  # one fixed range for the whole volume
    return shown


def volume_limits(data: np.ndarray, data_range: tuple[float, float]) -> tuple[float, float]:
    """Contrast limits of a volume: its minimum to the :data:`VOLUME_PERCENTILE` of its non-zero voxels.

    A reconstruction of beads has a few bright voxels per bead over a faint positive floor: with the
    maximum as the limit (and a linear look) only the brightest voxel of each bead lit, about a screen
    pixel in a 530-voxel slice, and the view read as empty. A volume with few non-zero voxels (a
    phantom) keeps about its maximum.
    """
    flat = torch.from_numpy(data.reshape(-1))
    nonzero = flat[flat != 0]
    if not nonzero.numel():
        return data_range
    if nonzero.numel() > PERCENTILE_SAMPLES:
        nonzero = nonzero[
            torch.from_numpy(np.random.default_rng(0).integers(0, nonzero.numel(), PERCENTILE_SAMPLES))
        ]
    high = float(np.percentile(nonzero.numpy(), VOLUME_PERCENTILE))
    low = data_range[0]
    return (low, high) if high > low else data_range


def brightest_slice(data: np.ndarray) -> int:
    """Index along the depth axis (third last) of the slice holding the volume's maximum."""
    if data.ndim < 3 or not data.size:
        return 0
    peaks = torch.from_numpy(data).reshape(-1, *data.shape[-3:]).amax(dim=(0, 2, 3))
    return int(peaks.argmax())


#: Lateral size at or below which no further pyramid level is made (about a canvas width).
PYRAMID_STOP_PIXELS = 512


def pyramid_levels(data: np.ndarray, *, max_voxels_3d: int = DEFAULT_MAX_VOXELS_3D) -> tuple[np.ndarray, ...]:
    """Lateral 2 x 2 max-pooled levels of ``data (..., Y, X)`` below full resolution.

    Levels are made while the current one is wider than :data:`PYRAMID_STOP_PIXELS` or its
    3-D block (last three axes) holds more than ``max_voxels_3d`` voxels; none for small
    data. Max pooling keeps sparse bright points (PSF spots, beads) visible where averaging
    or subsampling would dim or drop them.
    """
    levels: list[np.ndarray] = []
    current = data
    while min(current.shape[-2:]) >= 2 and (
        max(current.shape[-2:]) > PYRAMID_STOP_PIXELS or math.prod(current.shape[-3:]) > max_voxels_3d
    ):
        flat = torch.from_numpy(current).reshape(-1, 1, *current.shape[-2:])
        pooled = torch.nn.functional.max_pool2d(flat, 2, 2, ceil_mode=True)
        current = pooled.reshape(*current.shape[:-2], *pooled.shape[-2:]).numpy()
        levels.append(current)
    return tuple(levels)


def _finish(shown: DisplayData, max_voxels_3d: int) -> DisplayData:
    """Fill the range and the pyramid (the expensive passes over the data)."""
    shown.data_range = _range(shown.data)
    shown.levels = pyramid_levels(shown.data, max_voxels_3d=max_voxels_3d)
    return shown


def describe(shown: DisplayData, *, stretched: bool = True) -> str:
    """One line for the info label: what the layer is, its sampling in um (and the depth stretch)."""
    meta, shape = shown.metadata, "×".join(str(n) for n in shown.data.shape)
    note = f" ({meta['note']})" if meta.get("note") else ""
    if meta["kind"] == "psf":
        depths = meta["depths_um"]
        return (
            f"{shown.name}: {shape} ({meta['model']}), {len(depths)} depths {depths[0]:+g} to {depths[-1]:+g} µm; "
            f"sensor pixels {meta['pixel_size_um']:g} µm{note} (sample side {meta['sample_pixel_size_um']:.3g} µm)"
            + (f"; depth drawn ×{shown.z_stretch:g}" if stretched and shown.z_stretch != 1 else "")
        )
    if meta["kind"] == "image":
        return f"{shown.name}: {shape} camera pixels of {meta['pixel_size_um']:g} µm{note}"
    dz, dy, dx = meta["voxel_size_um"]
    return f"{shown.name}: {shape} voxels of {dz:g}×{dy:g}×{dx:g} µm (z×y×x, sample side)"


def depth_axis_um(shown: DisplayData) -> np.ndarray:
    """Sample-side depth of each slice in um, as drawn (the display stretch removed)."""
    z = shown.z_axis
    return shown.translate_um[z] + shown.scale_um[z] * np.arange(shown.data.shape[z])


def nearest_depth_index(shown: DisplayData, depth_um: float) -> int:
    """Index of ``shown``'s slice nearest ``depth_um`` (sample side): where a stack replacing
    another keeps the depth that was on screen (the 5-depth preview's z = 0 stays z = 0)."""
    return int(np.argmin(np.abs(depth_axis_um(shown) - depth_um)))


def _numpy(tensor: torch.Tensor) -> np.ndarray:
    if not isinstance(tensor, torch.Tensor):
        raise TypeError(f"expected a torch.Tensor, got {type(tensor).__name__}.")
    if tensor.is_complex():
        raise TypeError("expected a real tensor (intensities); got a complex one. Fix: pass .abs() ** 2.")
    return tensor.detach().to(device="cpu", dtype=torch.float32).contiguous().numpy()


def _require_size(name: str, value: Any) -> float:
    """``value`` as a float when it is a finite positive size in metres (floats, numpy or 0-d tensors)."""
    try:
        size = float(value)
    except (TypeError, ValueError):
        size = math.nan
    if not (math.isfinite(size) and size > 0):
        raise ValueError(f"{name} must be a positive size in metres (e.g. 6.5e-6); got {value!r}.")
    return size


def _depth_step(depths_um: np.ndarray, fallback_um: float) -> tuple[float, bool]:
    """Mean depth step in um (napari needs one) and whether the depths are evenly spaced."""
    if depths_um.size < 2:
        return fallback_um, True
    steps = np.diff(depths_um)
    step = float((depths_um[-1] - depths_um[0]) / (depths_um.size - 1))
    return step, bool(np.allclose(steps, step, rtol=1e-6, atol=1e-9))


def _z_stretch(z_span_um: float, lateral_um: float) -> float:
    """Display-only axial stretch: 1 unless depth is < 1/4 of the lateral span (then a 1-2-5 value)."""
    ratio = lateral_um / (2.0 * z_span_um) if z_span_um > 0 else 1.0
    if ratio <= 2.0:
        return 1.0
    decade = 10.0 ** math.floor(math.log10(ratio))
    return max(m * decade for m in (1.0, 2.0, 5.0) if m * decade <= ratio)


def _axis_names(count: int) -> tuple[str, ...]:
    return tuple(f"axis {i}" for i in range(count))


def _range(data: np.ndarray) -> tuple[float, float]:
    """``(min, max)`` in one pass (torch.aminmax), widened to a non-empty interval."""
    if not data.size:
        return (0.0, 1.0)
    low, high = (float(v) for v in torch.aminmax(torch.from_numpy(data)))
    return (low, high) if high > low else (low, low + 1.0)


def _robust_limits(data: np.ndarray, *, floor: float | None = None) -> tuple[float, float]:
    """0.1 / 99.9 percentiles (:data:`ROBUST_PERCENTILES`) of ``data``, the low one at least ``floor``.

    Large data is sampled at :data:`PERCENTILE_SAMPLES` random positions (fixed seed: regular
    strides alias with the regular spot grid of a Fourier-LFM PSF). When the high percentile
    does not exceed the low one (fewer than 0.1 % non-zero pixels, constant data) the high
    limit is the data maximum, so the brightest structure is never clipped away entirely.
    """
    flat = data.reshape(-1)
    if not flat.size:
        return (0.0, 1.0)
    if flat.size > PERCENTILE_SAMPLES:
        picks = np.random.default_rng(0).integers(0, flat.size, PERCENTILE_SAMPLES)
        flat = flat[picks]
    low, high = (float(v) for v in np.percentile(flat, ROBUST_PERCENTILES))
    if floor is not None:
        low = max(low, floor)
    if not high > low:
        high = float(data.max())
    return (low, high) if high > low else _range(data)
