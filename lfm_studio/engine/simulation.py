"""The headless simulation pipeline shared by the CLI, the studio and the napari plugin.

Design -> PSF stack (Fourier or conventional) -> projector -> phantom volume ->
light-field image with camera noise. Each step is a plain function; none imports Qt.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Sequence

import torch

from lfm_studio.engine.design import Design, DesignWarning, list_presets
from lfm_studio.engine.dtypes import real_dtype_named
from lfm_studio.engine.errors import as_real_tensor, listed, require_device, require_non_negative
from lfm_studio.engine.memory import require_memory, tensor_bytes
from lfm_studio.engine.optics.camera import Camera, SaturationWarning, saturation_note, simulate_sensor
from lfm_studio.engine.phantoms import DEFAULT_BEADS, beads, cells_in_ellipsoid, default_bead_count
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.fourier_psf import FourierPSFReport
from lfm_studio.engine.systems.kinds import ImagingSetup, Projector, kind_of, stack_kind
from lfm_studio.engine.systems.lenslet_cache import LensletCache
from lfm_studio.engine.types import TensorLike
from lfm_studio.engine.units import um

__all__ = [
    "ImagingSetup",
    "Projector",
    "camera_of",
    "depth_grid",
    "design_depths",
    "imaging_setup",
    "light_field_image",
    "make_phantom",
    "photons_per_unit",
    "require_psf_memory",
    "simulate_psf",
    "source_depths",
]


def _valid_range(depths_um: tuple[float, float, float]) -> str:
    """``depths_um`` put in order (STOP >= START, STEP > 0) as START:STOP:STEP, for a fix."""
    start, stop, step = depths_um
    if not (math.isfinite(start) and math.isfinite(stop)):
        return "-40:40:10"
    step = abs(step) if math.isfinite(step) and step else 5.0
    return f"{min(start, stop):g}:{max(start, stop):g}:{step:g}"


def depth_grid(depths_um: tuple[float, float, float], name: str = "depths") -> tuple[float, ...]:
    """Depths in metres from ``depths_um = (start, stop, step)`` in um (stop included when on the
    grid); ``name`` is the parameter named in the error."""
    start, stop, step = depths_um
    if not (all(math.isfinite(v) for v in depths_um) and step > 0 and stop >= start):
        raise ValueError(
            f"{name} must be START:STOP:STEP in um (finite numbers) with STEP > 0 and STOP >= START; "
            f"got {':'.join(f'{v:g}' for v in depths_um)}. Fix: e.g. {name}={_valid_range(depths_um)}."
        )
    count = math.floor((stop - start) / step + 1e-9) + 1
    return tuple((start + i * step) * 1e-6 for i in range(count))


def design_depths(design: Design, depths_um: tuple[float, float, float] | None = None) -> tuple[float, ...]:
    """Depths in metres: :func:`depth_grid` of ``depths_um`` or, when ``None``, the design's."""
    return tuple(design.depths.values) if depths_um is None else depth_grid(depths_um)


MAX_DEPTH = 1e-3
"""Largest ``|depth|`` (m) :func:`simulate_psf` takes beyond a design's own depth range: a
microscope images a few hundred um around focus, and a depth of 1 mm or more is almost
surely micrometres passed as metres (10 "um" = 10 m)."""

FAR_MARGIN = 20e-6
"""Smallest distance (m) beyond a design's depth range at which :func:`source_depths` warns
(else the range's own width)."""


def _design_of(design: object) -> Design:
    """``design`` if it is a :class:`Design`; a preset name or file path is refused with the call
    that loads it (simulate_psf returns a stack whose design the rest of the pipeline reads)."""
    if isinstance(design, Design):
        return design
    if isinstance(design, (str, os.PathLike)):
        text = os.fspath(design)
        if text in list_presets():
            fix = f"design = load_preset({text!r})"
        elif text.endswith(".json") or os.path.isfile(text):
            fix = f"design = load_design({text!r})"
        else:
            presets = ", ".join(list_presets())
            fix = f"design = load_preset(name) ({presets}) or load_design(path) for a .json file"
        raise TypeError(
            f"design must be a Design; got the {type(design).__name__} {text!r}. Fix: {fix} "
            "(from lfm_studio.engine.design), then simulate_psf(design, ...)."
        )
    raise TypeError(
        f"design must be a Design; got an object of type {type(design).__name__}. Fix: load one with "
        "load_preset(name) or load_design(path) (from lfm_studio.engine.design)."
    )


def source_depths(design: Design, depths: float | Sequence[float] | torch.Tensor | None) -> tuple[float, ...]:
    """The depths in metres :func:`simulate_psf` computes, checked before any work.

    ``None``: the design's (:func:`design_depths`); one number: that one depth. Refused with a
    ``ValueError`` naming ``depths``: a value that is not a finite number, and a ``|depth|`` of
    :data:`MAX_DEPTH` (1 mm) or more beyond the design's own range (micrometres passed as
    metres). Depths farther than the range's width (at least :data:`FAR_MARGIN`) outside it
    give a :class:`DesignWarning`: the design was not sized for them (views may leave a crop).
    """
    own = design_depths(design)
    if depths is None:
        return own
    if isinstance(depths, (str, bytes)):
        raise TypeError(
            f"depths must be numbers in metres, not text; got {depths!r}. Fix: e.g. "
            "depths=(-10 * um, 0.0, 10 * um) with um from lfm_studio.engine.units (a START:STOP:STEP range "
            "in um: depth_grid((-10, 10, 5)))."
        )
    try:
        items = list(depths)  # type: ignore[arg-type]
    except TypeError:  # one number (also a 0-d tensor or array)
        items = [depths]
    try:
        values = tuple(float(z) for z in items)
    except (TypeError, ValueError):
        raise TypeError(
            f"depths must be a number or a sequence of numbers in metres; got {depths!r}. "
            "Fix: e.g. depths=(-10 * um, 0.0, 10 * um) with um from lfm_studio.engine.units."
        ) from None
    if not all(math.isfinite(z) for z in values):
        raise ValueError(
            f"depths must be finite numbers in metres; got ({listed(values)}) m. "
            "Fix: e.g. depths=(-10 * um, 0.0, 10 * um) with um from lfm_studio.engine.units."
        )
    lo, hi = min(own), max(own)
    reach = max(abs(lo), abs(hi))
    far = [z for z in values if abs(z) >= MAX_DEPTH and abs(z) > reach]
    if far:
        if max(abs(z) for z in values) >= 1.0:
            fix = f"did you pass um? Use depths=({listed(values, unit=' * um')})"
        else:
            fix = "give depths in metres, e.g. depths=(-10 * um, 0.0, 10 * um)"
        raise ValueError(
            f"depths must be in metres, within {max(MAX_DEPTH, reach) * 1e3:g} mm of focus; got "
            f"({listed(values)}) m, {abs(far[0]):g} m from focus, not a depth a microscope images (this "
            f"design's range is {lo / um:g} .. {hi / um:g} um). Fix: {fix} with um from lfm_studio.engine.units."
        )
    margin = max(hi - lo, FAR_MARGIN)
    outside = [z for z in values if not lo - margin <= z <= hi + margin]
    if outside:
        warnings.warn(
            f"depths ({listed(outside, um)}) um lie far outside the design's depth range {lo / um:g} .. "
            f"{hi / um:g} um (more than {margin / um:g} um beyond it): the design was not sized for them, "
            "and with crop= the views that leave the crop are lost. Fix: check that the depths are in metres "
            "(10 um = 10e-6), or widen the design's depth_range_um to cover them.",
            DesignWarning,
            stacklevel=3,
        )
    return values


def simulate_psf(
    design: Design,
    *,
    depths: float | Sequence[float] | torch.Tensor | None = None,
    device: torch.device | str = "cpu",
    dtype: str | torch.dtype | None = None,
    crop: int | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    cache: LensletCache | None = None,
    report: FourierPSFReport | None = None,
) -> PSFStack:
    """The PSF stack of ``design`` (Fourier: ``(Z, Y, X)`` sensor PSFs; conventional: patterns
    ``(S, S, Z, H, H)`` with ``stack.patterns``) at ``depths`` metres (default: the design's;
    one number is one depth; checked by :func:`source_depths`), with the design attached;
    computed by the design's system kind (:func:`kind_of`). ``dtype``: ``"float32"`` /
    ``"float64"`` or that torch dtype (default: the design's accuracy).

    Fourier with ``accuracy.volume_oversampling`` ``k > 1``: the PSFs are sampled on a virtual
    sensor ``k`` times finer (``(Z, k Y, k X)``, pixel pitch / k), recorded as
    ``stack.volume_oversampling``; :func:`imaging_setup` bins them onto the camera.

    ``crop``: keep only about ``crop x crop`` camera pixels around the axis, for quick studies
    (Fourier: the sensor cut to that size, views outside it are lost; conventional: the
    lenslets that fit in it). ``cache``: a per-lenslet cache, used by kinds that have one
    (``kind.lenslet_cache``); ``report``: filled with the method and the lenslets computed / cached.
    """
    design = _design_of(design)
    kind = kind_of(design)
    depths = source_depths(design, depths)
    real = real_dtype_named(dtype) if dtype is not None else None
    device = require_device(device)
    if crop is not None and not (isinstance(crop, int) and crop >= 1):
        raise ValueError(f"crop must be a positive number of camera pixels; got {crop!r}. Fix: e.g. 256.")
    ny, nx = design.camera.pixel_count
    sensor = (min(crop, ny), min(crop, nx)) if crop is not None else None
    require_psf_memory(design, len(depths), dtype=dtype, device=device, sensor=sensor)
    return kind.psf_stack(
        design, depths, device=device, dtype=real, crop=crop,
        cache=cache if kind.lenslet_cache else None, report=report, progress=progress, cancel=cancel,
    )  # fmt: skip


def require_psf_memory(
    design: Design,
    depth_count: int,
    *,
    dtype: str | torch.dtype | None = None,
    device: torch.device | str = "cpu",
    sensor: tuple[int, int] | None = None,
) -> None:
    """Refuse, before allocating, a PSF stack whose sensor-sized arrays cannot fit in memory.

    Lower bound of what :func:`simulate_psf` holds at once, from the design's kind
    (:meth:`SystemKind.psf_bytes`: a Fourier stack keeps ``depths x ny x nx`` reals plus a few
    complex sensor-sized fields, ``k`` times finer per axis with ``accuracy.volume_oversampling
    = k``; a conventional one at least a few complex sensor-sized fields). ``sensor``: the
    (cropped) sensor in camera pixels, default the design's (named in the error).
    """
    ny, nx = sensor if sensor is not None else design.camera.pixel_count
    real = real_dtype_named(dtype) if dtype is not None else torch.float32
    needed = kind_of(design).psf_bytes(design, depth_count, (ny, nx), real)
    require_memory(
        needed,
        f"the PSF stack of {design.name!r} ({depth_count} depths on a {ny} x {nx} px sensor)",
        "reduce camera.pixel_count in the design (crop the sensor), simulate fewer depths (--depths), "
        "or run on a machine with more memory.",
        device=device,
    )


def imaging_setup(stack: PSFStack, *, field_of_view: float | None = None) -> ImagingSetup:
    """Projector and volume grid for ``stack``, built by the kind of its layout (:func:`stack_kind`).

    Fourier (and any per-depth shift-invariant stack): lateral voxel = the stack's pixel /
    magnification (sensor pixel / M_T, or ``1 / k`` of it for a stack with
    ``volume_oversampling`` ``k``, whose PSFs are then summed ``k x k`` onto each camera pixel:
    :class:`BinnedProjector`); the volume spans ``field_of_view`` metres (default: the design's,
    else a quarter of the sensor). Conventional: the lattice of the stack's lenslets,
    ``voxels_per_lenslet`` per pitch (``stack.patterns``).
    """
    return stack_kind(stack).imaging_setup(stack, field_of_view=field_of_view)


def make_phantom(
    kind: str,
    setup: ImagingSetup,
    *,
    seed: int,
    count: int | None = None,
    dtype: torch.dtype = torch.float32,
) -> tuple[torch.Tensor, dict]:
    """A seeded volume on the setup's grid: ``"beads"`` (``count`` points) or ``"cells"``
    (cell-like spheres filling the largest ellipsoid that fits, 3 um radius).

    ``count=None`` (the default) gives :func:`~lfm_studio.engine.phantoms.default_bead_count`
    beads: 50, or what fits in a small volume; ``info["note"]`` then says how many and why.
    An explicit ``count`` below 1 (an all-zero volume) or one that does not fit is an error.
    """
    if count is not None and (isinstance(count, bool) or not isinstance(count, int) or count < 1):
        raise ValueError(
            f"count must be an int >= 1 (beads to place; 0 gives an all-zero volume); got {count!r}. "
            f"Fix: count=1 or more, or count=None for the default ({DEFAULT_BEADS}, or what fits)."
        )
    shape, voxel = setup.volume_shape, setup.voxel_size
    require_memory(
        3 * tensor_bytes(shape, dtype),
        f"a phantom volume of {shape} voxels",
        "crop the sensor (camera.pixel_count) or simulate fewer depths.",
    )
    note = None
    if kind == "beads" and count is not None:
        phantom = beads(shape, count=count, voxel_size=voxel, seed=seed, dtype=dtype)
    elif kind == "beads":
        wanted = default_bead_count(shape, voxel)
        phantom = beads(shape, count=wanted, voxel_size=voxel, seed=seed, dtype=dtype, allow_fewer=True)
        if phantom.count < DEFAULT_BEADS:
            note = (
                f"placed {phantom.count} beads, not the default {DEFAULT_BEADS}: more do not fit "
                f"{2 * max(voxel) * 1e6:.3g} um apart in a volume of {shape} voxels. Fix: pass --count N "
                "(at most what fits), or use more depths / a larger field of view."
            )
    elif kind == "cells":
        semi = (0.45 * shape[0] * voxel[0], 0.45 * shape[1] * voxel[1], 0.45 * shape[2] * voxel[2])
        phantom = cells_in_ellipsoid(shape, voxel_size=voxel, seed=seed, semi_axes=semi, dtype=dtype)
    else:
        raise ValueError(f"phantom must be 'beads', 'cells' or a TIFF volume path; got {kind!r}.")
    info = {"phantom": kind, "seed": seed, "objects": int(phantom.count)}
    if note is not None:
        info["note"] = note
    return phantom.data, info


def camera_of(design: Design) -> Camera:
    """The engine camera of ``design`` (noise parameters; SI pixel pitch)."""
    spec = design.camera
    return Camera(
        pixel_pitch=spec.pixel_pitch,
        quantum_efficiency=spec.quantum_efficiency,
        read_noise=spec.read_noise_e,
        gain=spec.gain_adu_per_e,
        bit_depth=spec.bit_depth,
        baseline=spec.baseline_adu,
        full_well=spec.full_well_e,
    )


def light_field_image(
    setup: ImagingSetup,
    volume: TensorLike,
    camera: Camera,
    *,
    photons: float | None,
    seed: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(counts, expected)``: camera counts (ADU) with shot and read noise, and the noise-free image.

    ``volume`` ``(Z, Y, X)`` on ``setup``'s grid (a tensor or a numpy array, taken in the
    projector's dtype and device) is emitted light per voxel, so it must be finite and
    ``>= 0`` (``ValueError`` naming ``volume`` otherwise).

    ``counts`` are in ADU, the camera's baseline included: whole numbers in a float tensor, clipped
    to ``[0, 2^bits - 1]`` (:func:`~lfm_studio.engine.optics.camera.digitize`). ``expected`` is ``A volume``
    (clamped at 0) in the volume's units per pixel, neither photons nor ADU: a unit point source
    puts the PSF stack's per-depth sum on the sensor. :func:`photons_per_unit` gives the photons
    per unit of it (``photons / expected.sum()``).

    ``photons`` is the expected number of photons reaching the camera in the image;
    ``None`` gives the noise-free expected image (also returned as ``counts``, then in the
    volume's units, not ADU). With ``photons``, a volume that puts no light on the camera is
    refused (there is nothing to scale), and pixels driven past the full well or the ADC's
    top give a :class:`~lfm_studio.engine.optics.camera.SaturationWarning` with their count.
    """
    projector = setup.projector
    ny, nx = projector.image_shape
    volume = as_real_tensor("volume", volume, dtype=projector.dtype, device=torch.device(projector.device))
    require_memory(
        4 * tensor_bytes((ny, nx), volume.dtype),
        f"a light-field image of {ny} x {nx} pixels",
        "crop the sensor (camera.pixel_count).",
        device=volume.device,
    )
    require_non_negative(
        "volume",
        volume,
        "a volume is the light emitted per voxel: clip it with volume.clamp(min=0), or check its sign "
        "and offset.",
    )
    expected = projector.forward(volume).clamp_min(0.0)
    if photons is None:
        return expected, expected
    if not photons > 0:
        raise ValueError(f"photons must be > 0 (expected photons in the image); got {photons!r}.")
    if not float(expected.detach().double().sum()) > 0:
        raise ValueError(
            f"volume puts no light on the camera (volume sum {float(volume.detach().double().sum()):.6g}, "
            f"its image A volume sums to 0), so photons={photons:g} cannot be placed: the image would be "
            "the baseline alone. Fix: give a volume with emitters inside the projector's field (e.g. "
            "make_phantom('beads', setup, seed=0)), or photons=None for the noise-free image."
        )
    counts = simulate_sensor(expected, camera, photons=photons, generator=seed)
    note = saturation_note(expected, camera, photons=photons)
    if note is not None:
        warnings.warn(note, SaturationWarning, stacklevel=2)
    return counts, expected


def photons_per_unit(expected: torch.Tensor, photons: float | None) -> float:
    """Photons at the camera per unit of the noise-free image ``expected`` (``photons / sum``; 1 when
    ``photons`` is None): times the phantom, it gives the ground truth in photons per voxel, the
    unit a reconstruction from photons (:func:`~lfm_studio.engine.io.counts_to_photons`) comes out in."""
    if photons is None:
        return 1.0
    total = float(expected.detach().double().sum())
    return photons / total if total > 0 else 0.0
