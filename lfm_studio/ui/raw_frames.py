"""A raw camera frame of a real instrument, made ready for the studio's reconstruction (Qt-free).

:func:`load_raw_frame` runs on a worker thread (:mod:`lfm_studio.widgets.jobs`): it reads the raw
TIFF, loads the calibration file or makes a calibration from a radiometry (and dark) frame
against the studio's design (``lfm_studio.engine.calibration``, with progress and cancel),
corrects and rectifies the frame, converts it to photons (baseline 0: the calibration
subtracted the dark frame) and names the design whose PSF images it: the rectified design of
a conventional LFM, the fitted design of a Fourier LFM. Nothing in the studio changes until
the result is installed by :func:`raw_image_result` on the GUI thread, and a calibration made
here is saved (:func:`save_made_calibration`) only after that, so a cancelled or failed load
leaves the previous state, and the file it would have replaced, as they were.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from lfm_studio.engine.design import Design
from lfm_studio.ui.results import ImageResult

_STEPS = 4


@dataclass(frozen=True)
class RawFrameRequest:
    """What to load.

    Attributes
    ----------
    raw : the raw camera TIFF (one frame).
    calibration : a calibration file (``lfm-studio calibrate``), or None to make one from
        ``radiometry`` (and ``dark``) against ``design``.
    save_calibration : where to save a calibration made here (None: not saved), once the
        frame is in the studio (:func:`save_made_calibration`).
    overwrite_calibration : the user agreed to replace an existing ``save_calibration`` file.
    design : the studio's design (the nominal optics a calibration is made against).
    """

    raw: Path
    design: Design
    calibration: Path | None = None
    radiometry: Path | None = None
    dark: Path | None = None
    save_calibration: Path | None = None
    overwrite_calibration: bool = False

    def __post_init__(self) -> None:
        for name in ("raw", "calibration", "radiometry", "dark", "save_calibration"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, Path(value).expanduser())
        if self.calibration is None and self.radiometry is None:
            raise ValueError(
                "a raw frame needs a calibration file or a radiometry frame to make one. Fix: choose a "
                "calibration (.json) or a radiometry frame (.tif)."
            )


@dataclass(frozen=True)
class RawFrame:
    """A raw frame corrected and rectified with its calibration.

    Attributes
    ----------
    photons : (Y, X) float32 photons per pixel of the PSF design's sensor.
    noise_floor : photons per pixel the camera's read noise adds (the background to model).
    calibration : the calibration used (``lfm_studio.engine.calibration.Calibration``).
    psf_design : the design whose PSF images ``photons`` (rectified or fitted).
    request : what was asked.
    display : ``photons`` prepared for the viewer (``image_display``).
    info : what the image records (file names, calibration summary).
    """

    photons: torch.Tensor
    noise_floor: float
    calibration: Any
    psf_design: Design
    request: RawFrameRequest
    display: Any = None
    info: dict[str, Any] = field(default_factory=dict)


def _raw(path: Path, pixel_size: float):
    from lfm_studio.engine.io import read_image

    if not Path(path).is_file():
        raise FileNotFoundError(
            f"raw frame {path}: no such file. Fix: choose the camera TIFF to reconstruct."
        )
    image = read_image(path, pixel_size=pixel_size, dtype=torch.float64)
    data = image.data
    if data.ndim == 3 and data.shape[0] > 1:
        raise ValueError(
            f"raw frame {path} holds {data.shape[0]} frames; the studio reconstructs one. Fix: save one frame, "
            "or reconstruct the series with 'lfm-studio reconstruct --calibration'."
        )
    return (data[0] if data.ndim == 3 else data), image.metadata


def _calibration(ctx: Any, request: RawFrameRequest):
    from lfm_studio.engine.calibration import calibrate, load_calibration
    from lfm_studio.engine.calibration.frame_files import read_frame

    if request.calibration is not None:
        return load_calibration(request.calibration)
    if request.radiometry is None:  # excluded by RawFrameRequest
        raise ValueError("a radiometry frame is needed to make a calibration.")
    pixel = request.design.camera.pixel_pitch
    radiometry = read_frame("radiometry frame", request.radiometry, pixel)
    dark = None if request.dark is None else read_frame("dark frame", request.dark, pixel)

    def progress(done: int, total: int, message: str = "") -> None:
        ctx.progress(1, _STEPS, f"calibration: {message} ({done}/{total})")

    return calibrate(radiometry, request.design, dark=dark, progress=progress, cancel=ctx.cancel)


def save_made_calibration(frame: RawFrame) -> Path | None:
    """Save the calibration made by the load of ``frame`` where its request asks; returns the path.

    Called once the frame is in the studio (never from the job: a cancelled or failed load
    must not replace a file). None when nothing is to be saved (no path, or a calibration
    read from a file). Raises ``FileExistsError`` when the file exists and the user did not
    agree to replace it (``overwrite_calibration``), ``OSError`` when it cannot be written.
    """
    from lfm_studio.engine.calibration import save_calibration

    request = frame.request
    if request.save_calibration is None or request.calibration is not None:
        return None
    return save_calibration(
        frame.calibration, request.save_calibration, overwrite=request.overwrite_calibration
    )


def load_raw_frame(ctx: Any, request: RawFrameRequest) -> RawFrame:
    """The job: read, calibrate (or load the calibration), rectify, convert to photons."""
    from lfm_studio.engine.calibration import fitted_design, rectified_design, rectify_frame
    from lfm_studio.engine.calibration.raw_camera import dark_subtracted_camera
    from lfm_studio.engine.io import counts_to_photons
    from lfm_studio.widgets.viewer.display_data import image_display

    ctx.progress(0, _STEPS, "raw frame: reading")
    raw, metadata = _raw(request.raw, request.design.camera.pixel_pitch)
    ctx.check()
    ctx.progress(1, _STEPS, "raw frame: calibration")
    calibration = _calibration(ctx, request)
    ctx.check()
    ctx.progress(2, _STEPS, "raw frame: correcting and rectifying")
    try:
        frame = rectify_frame(raw, calibration)
    except ValueError as error:
        raise ValueError(f"raw frame {request.raw}: {error}") from error
    psf_design = (
        rectified_design(None, calibration)
        if calibration.grid is not None
        else fitted_design(None, calibration)
    )
    camera = dark_subtracted_camera(calibration, metadata, source="calibration (dark subtracted)")
    photons, floor = counts_to_photons(frame, camera, name=str(request.raw))
    ctx.check()
    ctx.progress(3, _STEPS, "raw frame: display")
    photons = photons.to(torch.float32)
    pixel = psf_design.camera.pixel_pitch
    made = "made from " + request.radiometry.name if request.radiometry is not None else None
    info = {
        "source": "raw frame",
        "raw_frame": str(request.raw),
        "calibration": str(request.calibration) if request.calibration is not None else made,
        "calibration_summary": calibration.summary(),
        "photons": None,  # already photons (pipeline.photon_counts)
        "noise_floor_photons": float(floor),
    }
    display = image_display(photons, pixel, "light field")
    ctx.progress(_STEPS, _STEPS, "raw frame: ready")
    return RawFrame(photons, float(floor), calibration, psf_design, request, display, info)


def raw_image_result(frame: RawFrame, psf_stack: Any) -> ImageResult:
    """The studio's light-field image for ``frame`` through ``psf_stack`` (no ground truth).

    Raises ``ValueError`` naming both shapes and the fix when the PSF images another frame shape.
    """
    from lfm_studio.engine.simulation import imaging_setup

    setup = imaging_setup(psf_stack)
    shape = tuple(setup.projector.image_shape)
    if shape != tuple(frame.photons.shape):
        raise ValueError(
            f"the rectified raw frame {frame.request.raw.name} has {tuple(frame.photons.shape)} pixels but the "
            f"studio's PSF images {shape}. Fix: open it again with the calibration's design "
            f"({frame.psf_design.name})."
        )
    return ImageResult(
        counts=frame.photons,
        expected=frame.photons,
        ground_truth=None,
        voxel_size=tuple(setup.voxel_size),
        pixel_size=psf_stack.pixel_size,
        setup=setup,
        info=dict(frame.info),
        display=frame.display,
    )
