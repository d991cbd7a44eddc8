"""A light-field reconstruction request from napari layers, checked before it starts (Qt-free).

:func:`prepare` checks what would otherwise fail minutes later or give nonsense: the
image and PSF pixel sizes match, the image has the PSF's sensor shape, and the
method suits the PSF kind; each refusal names the layers, the values and a fix.
:func:`run` turns camera counts into photons (the image's camera metadata, the
settings' baseline/gain, or an estimated baseline with a note), builds the projector and
reconstructs, reporting progress and stopping at the next iteration once ``cancel`` is
set (the engine's checkpoints). With a calibration (``lfm-studio calibrate``), the raw
frame is dark-subtracted, defect-corrected, flat-fielded and rectified onto the PSF's lattice
first (:func:`~lfm_studio.engine.calibration.rectify_frame`), and the camera conversion then
uses a baseline of 0 (:mod:`~lfm_studio.engine.calibration.raw_camera`): the dark level is
subtracted once. A result that is all zero, constant or NaN/Inf is
refused (:func:`~lfm_studio.engine.reconstruct.check_reconstruction`). The methods and their
options are the engine's registry (:mod:`lfm_studio.engine.reconstruct.registry`), as in
``lfm-studio reconstruct``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import torch

from lfm_studio.engine import reconstruct
from lfm_studio.engine.calibration import Calibration, rectify_frame
from lfm_studio.engine.calibration.raw_camera import dark_subtracted_camera
from lfm_studio.engine.io import LightFieldImage, Volume, counts_to_photons, resolve_calibration
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.reconstruct import registry
from lfm_studio.engine.simulation import imaging_setup
from lfm_studio.engine.systems.kinds import stack_kind
from lfm_studio.engine.units import um


@dataclass(frozen=True)
class Settings:
    """Reconstruction settings: a registered ``method`` and its ``options`` (checked against its schema
    and completed with its defaults on construction; ``background`` is the photons per pixel left after
    the camera baseline is removed), and the camera ``baseline`` (ADU) / ``gain`` (ADU per electron) for
    an image without camera metadata (None: from the image's metadata, else estimated)."""

    method: str = "rl"
    options: Mapping[str, Any] = field(default_factory=dict)
    baseline: float | None = None
    gain: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "options", registry.get(self.method).resolve(self.options))

    @property
    def label(self) -> str:
        """The method's label (for messages)."""
        return registry.get(self.method).label

    @property
    def background(self) -> float:
        """Expected background in photons per pixel (after the camera baseline)."""
        return float(self.options[registry.BACKGROUND.name])


@dataclass(frozen=True)
class Request:
    """A checked reconstruction: PSF stack, one camera frame, settings, the layer names (for messages)
    and an optional calibration of the raw frame (with its file name)."""

    stack: PSFStack
    image: LightFieldImage
    settings: Settings
    image_name: str
    psf_name: str
    calibration: Calibration | None = None
    calibration_name: str | None = None


def _check_raw_frame(
    image: LightFieldImage,
    settings: Settings,
    calibration: Calibration,
    image_name: str,
    calibration_name: str,
) -> None:
    """A raw frame that ``calibration`` can correct: the radiometry frame's shape, no second baseline."""
    if tuple(image.data.shape) != tuple(calibration.frame_shape):
        raise ValueError(
            f"The image layer {image_name!r} has {tuple(image.data.shape)} pixels but the calibration "
            f"{calibration_name!r} was measured on {tuple(calibration.frame_shape)}-pixel frames. Fix: pick the "
            "raw camera frame recorded with the same camera region (ROI) and binning, or calibrate again."
        )
    if settings.baseline is not None:
        raise ValueError(
            f"a baseline of {settings.baseline} ADU with the calibration {calibration_name!r}: the calibration "
            "subtracts its dark frame, a second baseline would subtract the dark level twice. Fix: no baseline."
        )


def prepare(
    stack: PSFStack,
    image: LightFieldImage,
    settings: Settings,
    *,
    image_name: str,
    psf_name: str,
    calibration: Calibration | None = None,
    calibration_name: str | None = None,
) -> Request:
    """Check that ``image`` can be reconstructed with ``stack`` and ``settings`` (a raw frame: after
    ``calibration``); raise ``ValueError`` if not."""
    if image.data.ndim != 2:
        raise ValueError(
            f"The image layer {image_name!r} has shape {tuple(image.data.shape)}; the reconstruct widget takes "
            "one camera frame (Y, X). Fix: pick a 2-D layer, or reconstruct time series with "
            "'lfm-studio reconstruct'."
        )
    kind = stack_kind(stack)
    method = registry.get(settings.method)
    if not method.supports_kind(kind):
        choices = " or ".join(m.label for m in registry.methods() if m.supports_kind(kind))
        raise ValueError(
            f"{settings.label} needs a {method.needs()}; {psf_name!r} is a {kind.title} pattern stack. "
            f"Fix: choose {choices}."
        )
    if calibration is not None:  # a raw frame: its rectified shape is checked against the PSF in run
        name = calibration_name or "calibration"
        _check_raw_frame(image, settings, calibration, image_name, name)
        return Request(stack, image, settings, image_name, psf_name, calibration, name)
    if not math.isclose(stack.camera_pixel_size, image.pixel_size, rel_tol=1e-6):
        raise ValueError(
            f"PSF pixel size does not match the image: the image layer {image_name!r} has "
            f"{image.pixel_size / um:g} um pixels but the PSF layer {psf_name!r} was computed for "
            f"{stack.camera_pixel_size / um:g} um sensor pixels. Fix: pick the PSF simulated for this camera, or "
            "simulate one with the camera's pixel pitch (Simulate PSF)."
        )
    if kind.shift_invariant and tuple(image.data.shape) != stack.camera_shape:
        raise ValueError(
            f"The image layer {image_name!r} has {tuple(image.data.shape)} pixels but the PSF layer "
            f"{psf_name!r} covers a {stack.camera_shape} pixel sensor. Fix: use the PSF simulated "
            "for this camera (same pixel count), or crop the image to it."
        )
    return Request(stack, image, settings, image_name, psf_name)


def _solve(
    request: Request,
    projector,
    photons: torch.Tensor,
    floor: float,
    progress: ProgressCallback,
    cancel: CancelToken,
) -> torch.Tensor:
    """Reconstruct ``photons``, which carry the camera's noise floor ``floor`` (photons per pixel)."""
    s = request.settings
    options = {**s.options, registry.BACKGROUND.name: s.background + floor}
    return reconstruct.reconstruct_frame(
        projector, photons, method=s.method, progress=progress, cancel=cancel, **options
    )


def run(request: Request, progress: ProgressCallback, cancel: CancelToken) -> Volume:
    """Reconstruct: the volume (object-space voxels, the PSF's depths; photons per voxel) with the settings,
    the camera calibration used and its ``notes`` (what was estimated) in its metadata."""
    checkpoint(cancel, progress, 0, 1, "building the projector")
    setup = imaging_setup(request.stack)
    s = request.settings
    frame, what = request.image.data, "has"
    if request.calibration is not None:
        checkpoint(cancel, progress, 0, 1, "rectifying the raw frame")
        frame = rectify_frame(frame.double().cpu(), request.calibration).to(request.image.data.dtype)
        what = f"rectified with {request.calibration_name!r} has"
    if tuple(frame.shape) != tuple(setup.projector.image_shape):
        raise ValueError(
            f"The image layer {request.image_name!r} {what} {tuple(frame.shape)} pixels but the PSF "
            f"layer {request.psf_name!r} images {tuple(setup.projector.image_shape)} pixels. Fix: use the PSF "
            "simulated for this camera"
            + (
                " (for a raw frame: 'lfm-studio calibrate ... --design-out rectified.json', then Simulate PSF "
                "from rectified.json)."
                if request.calibration is not None
                else "."
            )
        )
    if request.calibration is not None:
        source = f"calibration {request.calibration_name} (dark subtracted)"
        calibration = dark_subtracted_camera(
            request.calibration, request.image.metadata, gain=s.gain, source=source
        )
        notes: list[str] = []
    else:
        calibration, notes = resolve_calibration(
            request.image.metadata, frame, baseline=s.baseline, gain=s.gain
        )
    photons, floor = counts_to_photons(frame, calibration, name=f"image layer {request.image_name!r}")
    checkpoint(cancel, progress, 0, 1, s.label)
    volume = _solve(request, setup.projector, photons, floor, progress, cancel).detach().cpu()
    reconstruct.check_reconstruction(
        volume,
        what=f"the {s.label} reconstruction of {request.image_name!r} with {request.psf_name!r}",
    )
    metadata = {
        "method": s.method,
        **s.options,  # the method's options (iterations, snr, background, ...)
        "image": request.image_name,
        "psf": request.psf_name,
        "calibration": request.calibration_name,
        "units": calibration.volume_units,
        "camera": calibration.to_dict(),
        "notes": notes,
    }
    return Volume(volume, setup.voxel_size, request.stack.depths, metadata)
