"""A light-field video reconstructed into an OME-Zarr store as a studio background job (Qt-free).

:func:`reconstruct_video_job` runs on a worker thread (:mod:`lfm_studio.widgets.jobs`): it opens
the frames (a multi-page TIFF or a folder of TIFFs), builds the projector of the studio's
design, resolves the camera conversion (:func:`lfm_studio.engine.batch.camera.video_camera`, as
the command line does: the file's camera metadata, else the design's camera) and calls
:func:`lfm_studio.engine.batch.reconstruct_video` with the workflow panel's method and options,
its frame progress relayed to ``ctx.progress`` and ``cancel=ctx.cancel``. The engine refuses
frames of another shape (naming the file and both shapes) with the studio's fix
(:func:`frame_shape_fix`). A cancelled run stops between chunks and leaves a store that a
resumed run completes (only the missing and failed frames are computed). The result carries the
last reconstructed frame's volume for the viewer and the failed frames (recorded by the engine)
for the message.

Needs the optional ``scale`` extra (dask, zarr, ome-zarr): without it the job fails with the
engine's :class:`~lfm_studio.engine.batch.extras.MissingExtraError`, whose message says how to
install it; :func:`scale_missing` lets the menu say so before anything starts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch

from lfm_studio.engine.design import Design
from lfm_studio.ui.results import WorkflowSettings

DEFAULT_CHUNK_FRAMES = 4
LAYER = "video"  # the viewer layer of the last reconstructed frame


def scale_missing() -> str | None:
    """Why a video cannot be reconstructed here (the ``scale`` extra is missing, with the install
    line), or None when it can."""
    from lfm_studio.engine.batch.extras import MissingExtraError, require_scale

    try:
        require_scale()
    except MissingExtraError as error:
        return str(error)
    return None


@dataclass(frozen=True)
class VideoRequest:
    """What to reconstruct.

    Attributes
    ----------
    frames : a multi-page TIFF ``(T, Y, X)`` or a folder of single-frame TIFFs (sorted by name).
    output : the OME-Zarr store to write (``*.ome.zarr``).
    design : the studio's design (each worker builds the projector from it).
    settings : the workflow panel's settings (method, its options, iterations).
    resume : continue an existing store of the same run (only missing or failed frames are computed).
    overwrite : replace an existing store (the dialog asked).
    chunk_frames : frames per task and per status record.
    workers : worker processes of a local Dask cluster (None or 1: in this process).
    counts : the frames are camera counts (converted to photons); False: already photons.
    calibration : raw frames of a real microscope: the calibration file (``lfm-studio calibrate``)
        that corrects and rectifies each frame before the camera conversion; None: the frames are
        already the pixels the design images.
    """

    frames: Path
    output: Path
    design: Design
    settings: WorkflowSettings = field(default_factory=WorkflowSettings)
    resume: bool = False
    overwrite: bool = False
    chunk_frames: int = DEFAULT_CHUNK_FRAMES
    workers: int | None = None
    counts: bool = True
    calibration: Path | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "frames", Path(self.frames).expanduser())
        object.__setattr__(self, "output", Path(self.output).expanduser())
        if self.calibration is not None:
            object.__setattr__(self, "calibration", Path(self.calibration).expanduser())
            if not self.counts:
                raise ValueError(
                    f"calibration {self.calibration} with frames in photons: raw frames are camera counts "
                    "(the calibration subtracts the dark level in ADU). Fix: tick “Frames are camera counts”, "
                    "or clear the calibration."
                )
        if self.resume and self.overwrite:
            raise ValueError(
                f"{self.output}: resume and overwrite exclude each other. Fix: choose one (resume keeps "
                "the frames already done, overwrite starts again)."
            )
        if (
            isinstance(self.chunk_frames, bool)
            or not isinstance(self.chunk_frames, int)
            or self.chunk_frames < 1
        ):
            raise ValueError(
                f"chunk_frames must be a whole number >= 1; got {self.chunk_frames!r}. Fix: e.g. 4."
            )
        if self.workers is not None and (isinstance(self.workers, bool) or not isinstance(self.workers, int)
                                         or self.workers < 1):  # fmt: skip
            raise ValueError(f"workers must be a whole number >= 1; got {self.workers!r}. Fix: e.g. 1.")


@dataclass(frozen=True)
class VideoRun:
    """A finished video reconstruction.

    Attributes
    ----------
    request : what was asked.
    result : the engine's :class:`~lfm_studio.engine.batch.VideoResult` (path, frames computed
        now and before, failed frames with their errors, unfinished chunks).
    notes : what was assumed (the camera conversion).
    shown_frame : the frame whose volume is in ``volume`` (the last one reconstructed), or None
        when every frame failed.
    volume : ``(Z, Y, X)`` float32 of ``shown_frame`` (photons per voxel), or None.
    voxel_size : ``(dz, dy, dx)`` in metres.
    display : ``volume`` prepared for the viewer (layer :data:`LAYER`), or None.
    """

    request: VideoRequest
    result: Any
    notes: tuple[str, ...] = ()
    shown_frame: int | None = None
    volume: torch.Tensor | None = None
    voxel_size: tuple[float, float, float] = (1.0, 1.0, 1.0)
    display: Any = None

    def summary(self) -> str:
        """The message for the user: where, how many frames, which failed, what was assumed."""
        result = self.result
        done = len(result.computed) + len(result.skipped)
        lines = [
            f"Wrote {result.path}: {done} of {result.frame_count} frames reconstructed "
            f"({len(result.computed)} computed now, {len(result.skipped)} done before)."
        ]
        if result.failed:
            lines.append(f"{len(result.failed)} frame(s) failed (recorded in the store's lfm_studio_status):")
            lines.extend(f"  frame {t}: {error}" for t, error in result.failed.items())
            lines.append(
                "Fix: check those frames, then run again with “Resume”: only they are computed again."
            )
        if result.retried:
            lines.append(result.retried_note())
        if result.unfinished:
            lines.append(
                f"Chunks {list(result.unfinished)} were lost with their worker. Fix: run it again with "
                "“Resume” to finish them."
            )
        if self.shown_frame is not None:
            lines.append(f"The viewer shows frame {self.shown_frame} (layer “{LAYER}”).")
        lines.extend(self.notes)
        return "\n".join(lines)


def video_options(settings: WorkflowSettings) -> tuple[str, dict[str, Any]]:
    """The workflow panel's method and its options, as the studio's reconstruction stage builds them
    (:func:`~lfm_studio.ui.pipeline.reconstruction_options`); the background is 0 here: the engine
    adds each frame's camera noise floor."""
    from lfm_studio.engine.reconstruct import get_method
    from lfm_studio.ui.pipeline import reconstruction_options

    method = get_method(settings.method)
    return method.name, reconstruction_options(method, settings, 0.0)


def frame_shape_fix(design: Design) -> str:
    """The studio's fix for frames that are not the pixels the design's projector images (the end
    of the engine's refusal, :func:`lfm_studio.engine.batch.video.check_frame_shape`)."""
    return (
        f"open the design of the camera that recorded these frames (File > Open…; “{design.name}” has "
        f"camera.pixel_count {tuple(design.camera.pixel_count)}), or crop the frames to the pixels it images. "
        "Raw frames of a real microscope (lenslet grid off the pixel lattice) need their calibration: "
        "choose it in the dialog's Calibration field (a file from File > Open raw light field… or "
        "'lfm-studio calibrate'), with the rectified design open."
    )


RECTIFIED_FIX = (
    "open the rectified design (File > Open… rectified.json, written by Calibrate / "
    "lfm-studio calibrate --design-out)."
)
"""The studio's fix for raw frames whose rectified shape is not the open design's sensor."""


def _last_volume(result: Any) -> tuple[int | None, torch.Tensor | None]:
    import numpy as np
    import zarr

    done = [t for t in (*result.computed, *result.skipped) if t not in result.failed]
    if not done:
        return None, None
    frame = max(done)
    level0 = zarr.open_group(str(result.path), mode="r")["0"]
    return frame, torch.from_numpy(np.asarray(level0[frame], dtype=np.float32))


def reconstruct_video_job(ctx: Any, request: VideoRequest) -> VideoRun:
    """The job: frames -> projector of the design -> checks -> ``reconstruct_video`` -> last volume."""
    from lfm_studio.engine.batch.extras import require_scale

    require_scale()  # MissingExtraError: "... Fix: pip install "lfm-studio[scale]""
    from lfm_studio.engine.batch import open_frames, reconstruct_video
    from lfm_studio.engine.batch.camera import video_camera
    from lfm_studio.engine.batch.projectors import cached_projector, projector_spec
    from lfm_studio.engine.io.camera_counts import design_camera
    from lfm_studio.widgets.viewer.display_data import volume_display

    design = request.design
    method, options = video_options(request.settings)  # an unknown method or option: refused first
    ctx.progress(0, 0, f"opening {request.frames.name}")
    source = open_frames(request.frames)
    ctx.check()
    ctx.progress(0, source.count, f"building the projector of “{design.name}”")
    built = cached_projector(projector_spec(design))  # reconstruct_video reuses it in this process
    ctx.check()
    camera, notes = None, []
    if request.calibration is not None:  # the engine converts with the dark-subtracted camera
        notes = [
            f"Raw frames corrected and rectified with {request.calibration.name} before the camera conversion."
        ]
    elif request.counts:
        camera, notes = video_camera(
            source, fallback=design_camera(design.camera, f"the design's camera ({design.name})")
        )

    def progress(done: int, total: int, message: str = "") -> None:
        ctx.progress(done, total, f"{done}/{total} frames ({message})")

    result = reconstruct_video(
        source, design, method=method, options=options, output=request.output, resume=request.resume,
        overwrite=request.overwrite, workers=request.workers, chunk_frames=request.chunk_frames,
        camera=camera, progress=progress, cancel=ctx.cancel, shape_fix=frame_shape_fix(design),
        calibration=request.calibration, rectified_fix=RECTIFIED_FIX,
    )  # fmt: skip
    ctx.progress(source.count, source.count, "reading the last frame for the viewer")
    frame, volume = _last_volume(result)
    voxel_size = tuple(float(v) for v in built.setup.voxel_size)
    display = None if volume is None else volume_display(volume, voxel_size, LAYER)  # type: ignore[arg-type]
    return VideoRun(request, result, tuple(notes), frame, volume, voxel_size, display)  # type: ignore[arg-type]
