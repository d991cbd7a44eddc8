"""The headless simulation pipeline shared by the CLI, the studio and the napari plugin.

Design -> PSF stack (Fourier or conventional) -> projector -> phantom volume ->
light-field image with camera noise. Each step is a plain function; none imports Qt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from lfm_studio.engine.design import Design, RegularMLASpec
from lfm_studio.engine.dtypes import real_dtype_named
from lfm_studio.engine.memory import require_memory, tensor_bytes
from lfm_studio.engine.operators import Projector, ShiftInvariantProjector
from lfm_studio.engine.operators.binned import BinnedProjector
from lfm_studio.engine.optics.camera import Camera, simulate_sensor
from lfm_studio.engine.phantoms import DEFAULT_BEADS, beads, cells_in_ellipsoid, default_bead_count
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.conventional_psf import conventional_psf_stack, lattice_projector
from lfm_studio.engine.systems.fourier_psf import fourier_psf_stack
from lfm_studio.engine.systems.from_design import (
    conventional_accuracy_of,
    conventional_system_of,
    fourier_accuracy_of,
    fourier_system_of,
    virtual_pixel_count,
)
from lfm_studio.engine.systems.lenslet_cache import LensletCache


def depth_grid(depths_um: tuple[float, float, float], name: str = "depths") -> tuple[float, ...]:
    """Depths in metres from ``depths_um = (start, stop, step)`` in um (stop included when on the
    grid); ``name`` is the parameter named in the error."""
    start, stop, step = depths_um
    if not step > 0 or stop < start:
        raise ValueError(
            f"{name} must be START:STOP:STEP in um with STEP > 0 and STOP >= START; got {depths_um}."
        )
    count = math.floor((stop - start) / step + 1e-9) + 1
    return tuple((start + i * step) * 1e-6 for i in range(count))


def design_depths(design: Design, depths_um: tuple[float, float, float] | None = None) -> tuple[float, ...]:
    """Depths in metres: :func:`depth_grid` of ``depths_um`` or, when ``None``, the design's."""
    return tuple(design.depths.values) if depths_um is None else depth_grid(depths_um)


def simulate_psf(
    design: Design,
    *,
    depths: tuple[float, ...] | None = None,
    device: torch.device | str = "cpu",
    dtype: str | None = None,
    crop: int | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    cache: LensletCache | None = None,
) -> PSFStack:
    """The PSF stack of ``design`` (Fourier: ``(Z, Y, X)`` sensor PSFs; conventional: patterns
    ``(S, S, Z, H, H)``) at ``depths`` metres (default: the design's), with the design attached.

    Fourier with ``accuracy.volume_oversampling`` ``k > 1``: the PSFs are sampled on a virtual
    sensor ``k`` times finer (``(Z, k Y, k X)``, pixel pitch / k), recorded in the stack's
    metadata as ``volume_oversampling``; :func:`imaging_setup` bins them onto the camera.

    ``crop``: keep only about ``crop x crop`` camera pixels around the axis, for quick studies
    (Fourier: the sensor cut to that size, views outside it are lost; conventional: the
    lenslets that fit in it).

    ``cache``: a per-lenslet cache (Fourier kind, per-lenslet path) kept across calls, so a
    design that changes one lenslet recomputes one lenslet (the optimiser's grid search).
    """
    depths = tuple(depths) if depths is not None else design_depths(design)
    refine = design.accuracy.volume_oversampling
    if crop is not None and not (isinstance(crop, int) and crop >= 1):
        raise ValueError(f"crop must be a positive number of camera pixels; got {crop!r}. Fix: e.g. 256.")
    ny, nx = design.camera.pixel_count
    sensor = (min(crop, ny), min(crop, nx)) if crop is not None else None
    require_psf_memory(design, len(depths), dtype=dtype, device=device, sensor=sensor)
    real = real_dtype_named(dtype) if dtype is not None else None
    if design.kind == "fourier":
        fourier, accuracy = fourier_system_of(design, refine=refine), fourier_accuracy_of(design)
        if sensor is not None:
            shape = (virtual_pixel_count(sensor[0], refine), virtual_pixel_count(sensor[1], refine))
            fourier = replace(fourier, sensor_shape=shape)
        if real is not None:
            accuracy = replace(accuracy, dtype=real)
        stack = fourier_psf_stack(
            fourier,
            depths,
            accuracy=accuracy,
            device=device,
            progress=progress,
            cancel=cancel,
            design=design,
            cache=cache,
        )
    else:
        lenslets, mla = None, design.mla
        if crop is not None and isinstance(
            mla, RegularMLASpec
        ):  # (no pitch: conventional_system_of explains)
            count = max(1, int(crop * design.camera.pixel_pitch / (mla.pitch_um * 1e-6)))
            lenslets = (min(count, mla.shape[0]), min(count, mla.shape[1]))
        conventional = conventional_system_of(design, lenslets=lenslets)
        patterns = conventional_accuracy_of(design, conventional)
        if real is not None:
            patterns = replace(patterns, dtype=real)
        stack = conventional_psf_stack(
            conventional,
            depths,
            accuracy=patterns,
            device=device,
            progress=progress,
            cancel=cancel,
            design=design,
        )
    if design.kind == "fourier" and refine > 1:
        stack = replace(stack, metadata={**stack.metadata, "volume_oversampling": refine})
    return stack


def require_psf_memory(
    design: Design,
    depth_count: int,
    *,
    dtype: str | None = None,
    device: torch.device | str = "cpu",
    sensor: tuple[int, int] | None = None,
) -> None:
    """Refuse, before allocating, a PSF stack whose sensor-sized arrays cannot fit in memory.

    Lower bound of what :func:`simulate_psf` holds at once: a Fourier stack keeps
    ``depths x ny x nx`` reals plus a few complex sensor-sized fields (``k`` times finer per
    axis with ``accuracy.volume_oversampling = k``); a conventional one at least a few complex
    sensor-sized fields (its projector images the whole sensor). ``sensor``: the (cropped)
    sensor in camera pixels, default the design's.
    """
    ny, nx = sensor if sensor is not None else design.camera.pixel_count
    if design.kind == "fourier":
        refine = design.accuracy.volume_oversampling
        ny, nx = ny * refine, nx * refine
    real = real_dtype_named(dtype) if dtype is not None else torch.float32
    complex_type = torch.complex128 if real == torch.float64 else torch.complex64
    needed = 3 * tensor_bytes((ny, nx), complex_type)
    if design.kind == "fourier":
        needed += tensor_bytes((depth_count, ny, nx), real)
    require_memory(
        needed,
        f"the PSF stack of {design.name!r} ({depth_count} depths on a {ny} x {nx} px sensor)",
        "reduce camera.pixel_count in the design (crop the sensor), simulate fewer depths (--depths), "
        "or run on a machine with more memory.",
        device=device,
    )


@dataclass(frozen=True)
class ImagingSetup:
    """A projector with the volume grid it expects (voxel size in metres, ``(dz, dy, dx)``)."""

    projector: Projector
    volume_shape: tuple[int, int, int]
    voxel_size: tuple[float, float, float]


def imaging_setup(stack: PSFStack, *, field_of_view: float | None = None) -> ImagingSetup:
    """Projector and volume grid for ``stack``.

    Fourier: lateral voxel = the stack's pixel / magnification (sensor pixel / M_T, or
    ``1 / k`` of it for a stack with metadata ``volume_oversampling`` ``k``, whose PSFs are
    then summed ``k x k`` onto each camera pixel: :class:`BinnedProjector`); the volume
    spans ``field_of_view`` metres (default: the design's, else a quarter of the sensor).
    Conventional: the lattice of the stack's lenslets, ``voxels_per_lenslet`` per pitch.
    """
    depths = stack.depths
    dz = abs(depths[1] - depths[0]) if len(depths) > 1 else stack.object_pixel_size
    if stack.metadata.get("kind") == "conventional":
        lattice = lattice_projector(stack)
        voxel = (
            stack.pixel_size
            * stack.metadata_int("pixels_per_lenslet")
            / (stack.magnification * stack.metadata_int("voxels_per_lenslet"))
        )
        return ImagingSetup(lattice, lattice.volume_shape, (dz, voxel, voxel))
    voxel = stack.object_pixel_size
    if field_of_view is None and isinstance(
        stack.design, Design
    ):  # (a dict: a design read without rebuilding)
        field_of_view = stack.design.field_of_view_diameter or None
    ny, nx = stack.data.shape[-2:]
    lateral = min(ny, nx) // 4 if field_of_view is None else max(1, math.ceil(field_of_view / voxel))
    lateral += 1 - lateral % 2  # odd: a voxel on the optical axis
    projector: Projector = ShiftInvariantProjector(stack.data, (lateral, lateral))
    refine = stack.metadata_int("volume_oversampling", 1)
    if refine > 1:
        projector = BinnedProjector(projector, refine)
    return ImagingSetup(projector, (len(depths), lateral, lateral), (dz, voxel, voxel))


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
    An explicit ``count`` that does not fit is an error.
    """
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
        (nz, ny, nx), (dz, dy, dx) = shape, voxel
        semi = (0.45 * nz * dz, 0.45 * ny * dy, 0.45 * nx * dx)
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
    volume: torch.Tensor,
    camera: Camera,
    *,
    photons: float | None,
    seed: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(counts, expected)``: camera counts (ADU) with shot and read noise, and the noise-free image.

    ``photons`` is the expected number of photons reaching the camera in the image;
    ``None`` gives the noise-free expected image (also returned as ``counts``).
    """
    ny, nx = setup.projector.image_shape
    require_memory(
        4 * tensor_bytes((ny, nx), volume.dtype),
        f"a light-field image of {ny} x {nx} pixels",
        "crop the sensor (camera.pixel_count).",
        device=volume.device,
    )
    expected = setup.projector.forward(volume).clamp_min(0.0)
    if photons is None:
        return expected, expected
    if not photons > 0:
        raise ValueError(f"photons must be > 0 (expected photons in the image); got {photons!r}.")
    counts = simulate_sensor(expected, camera, photons=photons, generator=seed)
    return counts, expected


def photons_per_unit(expected: torch.Tensor, photons: float | None) -> float:
    """Photons at the camera per unit of the noise-free image ``expected`` (``photons / sum``; 1 when
    ``photons`` is None): times the phantom, it gives the ground truth in photons per voxel, the
    unit a reconstruction from photons (:func:`~lfm_studio.engine.io.counts_to_photons`) comes out in."""
    if photons is None:
        return 1.0
    total = float(expected.detach().double().sum())
    return photons / total if total > 0 else 0.0
