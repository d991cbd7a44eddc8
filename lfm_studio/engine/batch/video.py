"""Reconstruct a light-field video into a resumable OME-Zarr store, in-process or on Dask.

Example::

    from lfm_studio.engine.batch import reconstruct_video

    result = reconstruct_video("frames.tif", "flfm_guo2019", method="rl-accelerated",
                               iterations=10, output="run.ome.zarr", workers=2)
    print(result.failed)        # {frame: error} for frames that could not be reconstructed

A resume (the same call again) computes the frames without a record and those recorded as failed,
and keeps every frame recorded as done.
"""

from __future__ import annotations

import json
import os
import uuid
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from lfm_studio import __version__
from lfm_studio.engine.batch.camera import tiff_metadata
from lfm_studio.engine.batch.client import Client, check_placement, client_for, dashboard_link
from lfm_studio.engine.batch.frames import FrameSource, frame_digest, open_frames
from lfm_studio.engine.batch.options import ReconstructionOptions
from lfm_studio.engine.batch.projectors import (
    ProjectorSpec,
    cached_projector,
    planned_image_shape,
    projector_spec,
)
from lfm_studio.engine.batch.pyramid import level_count
from lfm_studio.engine.batch.raw_frames import RawFrameSpec, raw_frame_spec
from lfm_studio.engine.batch.store import (
    ChunkRecord,
    VideoStore,
    create_store,
    discard_store,
    finish_interrupted_replacement,
    listed_frames,
    open_store,
    replace_store,
)
from lfm_studio.engine.batch.tasks import ChunkTask, done_frames, process_chunk
from lfm_studio.engine.calibration import FrameRectifier, rectified_shape_fix
from lfm_studio.engine.calibration.raw_camera import dark_subtracted_camera
from lfm_studio.engine.design import Design
from lfm_studio.engine.io import CameraCalibration, OutputError
from lfm_studio.engine.io.file_checks import names_zarr_store
from lfm_studio.engine.progress import CancelledError, CancelToken, ProgressCallback, is_cancelled
from lfm_studio.engine.types import JSONValue, OptionValue

DEFAULT_CHUNK_FRAMES = 4
UM = 1e-6
LENSLETS_OPTION = "lenslets=({ny}, {nx}) (`--lenslets {ny} {nx}` on the command line)"
"""How a shape refusal of raw frames names the matching lenslet block (:func:`check_rectified_shape`)."""
FRAME_SHAPE_FIX = (
    "use the design/PSF of this camera (or crop= matching the frames); raw frames of a real "
    "microscope need calibration='calib.json' (from `lfm-studio calibrate`)."
)
"""What to do about frames of another shape (the end of :func:`check_frame_shape`'s refusal)."""


def check_frame_shape(source: FrameSource, sensor: tuple[int, ...], fix: str = FRAME_SHAPE_FIX) -> None:
    """Refuse frames whose ``(Y, X)`` pixels are not ``sensor``, the pixels the projector images:
    a ``ValueError`` naming the file, both shapes and ``Fix: <fix>``."""
    if tuple(source.shape[1:]) != tuple(sensor):
        raise ValueError(
            f"frames {source.path} are {tuple(source.shape[1:])} pixels but the projector images "
            f"{tuple(sensor)} pixels. Fix: {fix}"
        )


@dataclass(frozen=True)
class VideoResult:
    """What a call did.

    computed : frames reconstructed by this call.
    skipped : frames recorded as done before this call (not computed again).
    failed : frame -> error (``"Type: message"`` of its last attempt) for every frame the store
        holds as failed after this call; a resume tries them again.
    unfinished : chunks left without a record (a lost worker: resume to finish them).
    retried : frames an earlier call recorded as failed that this call tried again (now in
        ``computed`` or, failing again, in ``failed``).
    """

    path: str
    frame_count: int
    computed: tuple[int, ...]
    skipped: tuple[int, ...]
    failed: dict[int, str] = field(default_factory=dict)
    unfinished: tuple[int, ...] = ()
    dashboard: str | None = None
    retried: tuple[int, ...] = ()

    def retried_note(self) -> str | None:
        """One sentence on the earlier failures this call tried again (None when there were none)."""
        if not self.retried:
            return None
        again = [t for t in self.retried if t in self.failed]
        return (
            f"Frame(s) {list(self.retried)} had failed in an earlier run and were computed again: "
            f"{len(self.retried) - len(again)} reconstructed, {len(again)} failed again."
        )


def _run_record(source: FrameSource, spec_key: str, options: ReconstructionOptions, chunk_frames: int,
                camera: CameraCalibration | None, raw: RawFrameSpec | None) -> dict[str, JSONValue]:  # fmt: skip
    """What must match for a resume to continue the same reconstruction."""
    return {
        "frames": {"path": source.path, "shape": list(source.shape)},
        "projector": spec_key,
        "options": options.to_dict(),
        "chunk_frames": chunk_frames,
        "camera": None if camera is None else camera.to_dict(),
        "calibration": None if raw is None else raw.describe(),
    }


def _raw_frames(
    calibration: str | os.PathLike | None,
    lenslets: tuple[int, int] | None,
    source: FrameSource,
    camera: CameraCalibration | None,
) -> tuple[RawFrameSpec | None, FrameRectifier | None, CameraCalibration | None]:
    """The raw-frame spec, its rectifier and the camera conversion after it (baseline 0: the
    calibration subtracts its dark); without ``calibration``, none and ``camera`` unchanged."""
    if calibration is None:
        if lenslets is not None:
            raise ValueError(
                f"lenslets={tuple(lenslets)!r} needs calibration= (it picks the rectified block of raw "
                "frames). Fix: pass calibration='calib.json' or drop lenslets."
            )
        return None, None, camera
    if camera is not None and camera.baseline_adu != 0:
        raise ValueError(
            f"camera baseline {camera.baseline_adu:g} ADU with calibration {calibration}: the calibration "
            "subtracts its dark frame, a baseline would subtract the dark level twice. Fix: camera=None "
            "(the frames' metadata or the calibration's design camera, baseline 0) or a baseline of 0."
        )
    spec, rectifier = raw_frame_spec(calibration, lenslets)
    raw_shape = tuple(int(n) for n in rectifier.corrections.frame_shape)
    if tuple(source.shape[1:]) != raw_shape:
        raise ValueError(
            f"frames {source.path} are {tuple(source.shape[1:])} pixels but calibration {spec.path} was "
            f"measured on {raw_shape}-pixel frames. Fix: record with the same camera region (ROI) and "
            "binning as the radiometry frame, or calibrate again."
        )
    if camera is None:
        camera = dark_subtracted_camera(
            rectifier.calibration,
            tiff_metadata(source.path),
            source=f"calibration {spec.path} (dark subtracted)",
        )
    return spec, rectifier, camera


def check_rectified_shape(
    spec: RawFrameSpec, rectifier: FrameRectifier, sensor: tuple[int, ...], fix: str | None = None
) -> None:
    """Refuse raw frames whose rectified ``(Y, X)`` pixels are not ``sensor``, the pixels the
    projector images: a ``ValueError`` naming both shapes and ``Fix: <fix>`` (None: the PSF of the
    rectified design, or the lenslet block that matches this PSF, :data:`LENSLETS_OPTION`)."""
    shape = tuple(rectifier.output_shape)
    if shape == tuple(sensor):
        return
    worded = (
        rectified_shape_fix(rectifier.calibration, sensor, LENSLETS_OPTION) if fix is None else f"Fix: {fix}"
    )
    raise ValueError(
        f"raw frames rectified with {spec.path} are {shape} pixels but the projector images "
        f"{tuple(sensor)} pixels. {worded}"
    )


def _check_chunk_frames(chunk_frames: int) -> None:
    if isinstance(chunk_frames, bool) or not isinstance(chunk_frames, int) or chunk_frames < 1:
        raise ValueError(f"chunk_frames must be an integer >= 1; got {chunk_frames!r}. Fix: e.g. 4.")


def _frame_interval(frame_interval_s: float | None) -> float:
    if frame_interval_s is None:
        return 1.0
    if not frame_interval_s > 0:
        raise ValueError(f"frame_interval_s must be > 0 (seconds); got {frame_interval_s!r}. Fix: e.g. 1/30.")
    return float(frame_interval_s)


def _check_output(output: str | os.PathLike) -> None:
    """Refuse an output that does not name a Zarr store (``*.zarr``), as the CLI tells a video run
    by that suffix: a folder of chunks named ``out.tif`` would pass for a TIFF."""
    if not names_zarr_store(output):
        target = Path(output).expanduser()
        raise OutputError(
            f"output {target} does not end in .zarr, but reconstruct_video writes an OME-Zarr store (a "
            f"folder) there. Nothing was written. Fix: output={target.with_suffix('').name + '.ome.zarr'!r} "
            "(a single volume goes to a TIFF with reconstruct_frame and write_volume)."
        )


def _run_chunks(
    tasks: list[ChunkTask],
    client: Client | None,
    on_record: Callable[[ChunkRecord], None],
    cancel: CancelToken,
) -> list[int]:
    """Run ``tasks``; ``on_record(record)`` per finished chunk; returns the indices that were lost."""
    if client is None:
        import dask

        for task in tasks:
            if is_cancelled(cancel):
                raise CancelledError(f"stopped before chunk {task.index}; resume to finish")
            on_record(dask.delayed(process_chunk)(task).compute(scheduler="synchronous"))
        return []
    from distributed import KilledWorker, as_completed

    futures = client.map(process_chunk, tasks, pure=False)
    index_of = {future.key: task.index for future, task in zip(futures, tasks, strict=True)}
    lost = []
    try:
        for future in as_completed(futures):
            if is_cancelled(cancel):
                raise CancelledError("stopped by the caller; resume to finish")
            try:
                record = future.result()
            except KilledWorker:  # its workers kept dying: the chunk stays unrecorded (resume)
                lost.append(index_of[future.key])
                continue
            on_record(record)
    finally:
        client.cancel(futures)
    return sorted(lost)


class RecoveredStoreWarning(UserWarning):
    """A replacement that a crash stopped between its two renames was completed or undone."""


class FramesUncheckedWarning(UserWarning):
    """A store written before frame digests were kept is resumed: a changed recording cannot be told."""


def check_frames_unchanged(store: VideoStore, source: FrameSource) -> None:
    """Refuse to resume ``store`` when the recording under it changed: unless the frame files' stamp
    is the one kept, every frame recorded as done is read again and compared with its digest.

    A file repaired in place (failed frames rewritten, the others unchanged) resumes; another
    recording at the same path is refused, naming the frames that differ, before any work. A store
    written before stamps were kept resumes with a :class:`FramesUncheckedWarning`."""
    kept = store.frames_stamp()
    if kept == source.stamp():
        return
    if kept is None:
        warnings.warn(
            f"{store.path} was written before lfm_studio kept the frames' digests, so a changed {source.path} "
            "cannot be detected; resuming as before.",
            FramesUncheckedWarning,
            stacklevel=3,
        )
        return
    changed = []
    for record in store.records().values():  # one read per chunk, not per frame
        frames = source.read(record["start"], record["stop"])
        changed += [
            int(key)
            for key, info in record["frames"].items()
            if info["status"] == "done"
            and info.get("digest", "") != frame_digest(frames[int(key) - record["start"]])
        ]
    if changed:
        raise ValueError(
            f"frames {source.path} changed since {store.path} was written: frame(s) {listed_frames(changed)} "
            "differ from those reconstructed. Resuming would mix two recordings in one store. Fix: "
            "overwrite the store (start again), or write to another store."
        )


def _open_for_resume(
    target: Path, run: dict[str, JSONValue], legacy_run: dict[str, JSONValue] | None
) -> VideoStore:
    """The store at ``target`` to resume: its run record is ``run``, or ``legacy_run`` (the same run
    as an older version recorded it); refused naming what differs from ``run`` otherwise."""
    try:
        return open_store(target, run=run)
    except ValueError as error:
        if legacy_run is None:
            raise
        try:
            return open_store(target, run=legacy_run)
        except ValueError:
            raise error from None


def _prepare_store(output: str | os.PathLike, source: FrameSource, *, resume: bool, overwrite: bool,
                   run: dict[str, JSONValue],
                   attributes: dict[str, JSONValue], shape: tuple[int, int, int, int],
                   scale: tuple[float, float, float, float], origin: tuple[float, float, float, float],
                   levels: int, chunk_frames: int,
                   legacy_run: dict[str, JSONValue] | None = None) -> tuple[VideoStore, Path | None]:  # fmt: skip
    """The store to write and, for an overwrite of an existing store, the path it replaces when
    the run ends (the store returned is then a hidden sibling; the old one stays until then)."""
    target = Path(output).expanduser()
    recovered = finish_interrupted_replacement(target)  # a crash between replace_store's renames
    if recovered is not None:
        warnings.warn(recovered, RecoveredStoreWarning, stacklevel=3)
    if target.exists() and resume and not overwrite:
        store = _open_for_resume(target, run, legacy_run)
        check_frames_unchanged(store, source)
        return store, None
    replaces = target.absolute() if overwrite and target.exists() else None
    store = create_store(
        target, shape=shape, scale=scale, origin=origin, levels=levels, chunk_frames=chunk_frames,
        attributes=attributes, overwrite=overwrite,
    )  # fmt: skip
    return store, replaces


def reconstruct_video(
    frames: str | os.PathLike | FrameSource,
    design_or_psf: Design | str | os.PathLike,
    *,
    method: str = "rl-accelerated",
    options: Mapping[str, OptionValue] | None = None,
    output: str | os.PathLike = "run.ome.zarr",
    resume: bool = True,
    overwrite: bool = False,
    client: Client | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    chunk_frames: int = DEFAULT_CHUNK_FRAMES,
    frame_interval_s: float | None = None,
    camera: CameraCalibration | None = None,
    crop: int | None = None,
    field_of_view: float | None = None,
    dtype: str = "float32",
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    shape_fix: str = FRAME_SHAPE_FIX,
    calibration: str | os.PathLike | None = None,
    lenslets: tuple[int, int] | None = None,
    rectified_fix: str | None = None,
    **method_options: OptionValue,
) -> VideoResult:
    """Reconstruct every frame ``(T, Y, X)`` of ``frames`` into the OME-Zarr store ``output``.

    Parameters
    ----------
    frames : a (multi-page) TIFF, a folder of single-frame TIFFs, a Zarr/OME-Zarr array, or a
        :class:`FrameSource`; read lazily, chunk by chunk, by the workers. Photons per pixel,
        or camera counts when ``camera`` is given (converted per frame), or raw camera frames
        with ``calibration``.
    design_or_psf : a :class:`Design`, preset name, design file, or simulated PSF stack TIFF;
        each worker builds the projector once (``crop``: camera pixels kept around the axis).
    method, options, **method_options : a method of the reconstruction registry and its options
        (``options`` and keywords such as ``iterations=30``, ``background=2.0`` are merged; checked
        by the method's schema), as in :func:`~lfm_studio.engine.reconstruct.dispatch.reconstruct_frame`.
    output : the store, a name ending in ``.zarr`` (axes t, z, y, x; scales in s and um; a 2x
        lateral pyramid).
    resume : continue an existing store of the same run, computing only the frames not recorded
        as done (unrecorded chunks, and frames that failed before).
    overwrite : replace an existing store instead: the new run writes to a hidden sibling
        (``.NAME.replacing``) that takes the old store's place when the run ends (failed frames
        included); a cancelled, interrupted or failed run drops it and leaves the old store as it was.
    client, workers, scheduler : a Dask client to use; else ``workers`` N > 1 starts a
        LocalCluster of N one-thread processes, ``scheduler`` connects to a cluster, and
        neither runs the synchronous scheduler in this process.
    chunk_frames : frames per task (and per status record).
    frame_interval_s : time between frames (s); None records 1 s and notes it was assumed.
    progress, cancel : ``progress(frames_done, frame_count, message)`` per finished chunk; a set
        ``cancel`` stops between chunks with :class:`CancelledError` (the store stays resumable).
    shape_fix : the fix named when the frames are not the pixels the projector images
        (:func:`check_frame_shape`, before a design's PSF is simulated; a front end says it in its
        own words).
    calibration, lenslets : raw frames of a real microscope: the calibration file of
        ``lfm-studio calibrate``; each frame is dark-subtracted, defect-corrected, flat-fielded
        and (conventional LFM) rectified onto ``lenslets=(ny, nx)`` lenslets around the frame
        centre (None: the calibration's lit block), as
        :func:`~lfm_studio.engine.calibration.rectify_frame` does, before the camera conversion
        (``camera`` None: the frames' metadata, else the calibration's design camera, baseline 0).
    rectified_fix : the fix named when raw frames rectified with ``calibration`` are not the pixels
        the projector images (:func:`check_rectified_shape`; None: the PSF of the rectified design or
        the matching ``lenslets``, as the CLI and Python say it; a front end says it in its own words).

    The result's ``computed`` and ``skipped`` list the frames reconstructed (now, before);
    a frame that failed is only in ``failed``; ``retried`` lists the earlier failures tried again.
    """
    _check_output(output)
    reconstruction = ReconstructionOptions.of(method, {**(options or {}), **method_options})
    check_placement(client, workers, scheduler)
    _check_chunk_frames(chunk_frames)
    interval = _frame_interval(frame_interval_s)
    source = frames if isinstance(frames, FrameSource) else open_frames(frames)
    raw, rectifier, camera = _raw_frames(calibration, lenslets, source, camera)
    spec = projector_spec(design_or_psf, crop=crop, field_of_view=field_of_view, dtype=dtype)

    def check_shape(sensor: tuple[int, ...]) -> None:
        if raw is not None and rectifier is not None:
            check_rectified_shape(raw, rectifier, sensor, rectified_fix)
        else:
            check_frame_shape(source, sensor, shape_fix)

    planned = planned_image_shape(spec)
    if planned is not None:  # a design: refuse other frames before simulating its PSF
        check_shape(planned)
    built = cached_projector(spec)
    check_shape(tuple(built.setup.projector.image_shape))
    nz, ny, nx = (int(n) for n in built.setup.volume_shape)
    shape = (int(source.count), nz, ny, nx)
    levels = level_count((ny, nx))
    dz, dy, dx = built.setup.voxel_size
    scale = (interval, dz / UM, dy / UM, dx / UM)
    # first depth on z; y and x centred on the optical axis (the napari plugin's volume convention)
    origin = (0.0, built.depths[0] / UM, -(shape[2] // 2) * dy / UM, -(shape[3] // 2) * dx / UM)
    run = _run_record(source, spec.key, reconstruction, chunk_frames, camera, raw)
    attributes: dict[str, JSONValue] = {
        "version": __version__,
        "run": run,
        "method": reconstruction.method,
        "options": reconstruction.to_dict(),
        "projector": spec.describe(),
        "design": None if built.design_json is None else json.loads(built.design_json),
        "depths_um": [d / UM for d in built.depths],
        "voxel_size_um": [dz / UM, dy / UM, dx / UM],
        "frame_interval_s": interval,
        "frame_interval_assumed": frame_interval_s is None,
        "levels": levels,
        "chunk_frames": chunk_frames,
        "units": "photons per voxel" if camera is None else camera.volume_units,
    }
    legacy_run = None if raw is None else {**run, "calibration": raw.legacy_describe()}
    store, replaces = _prepare_store(
        output, source, resume=resume, overwrite=overwrite, run=run, attributes=attributes, shape=shape,
        scale=scale, origin=origin, levels=levels, chunk_frames=chunk_frames, legacy_run=legacy_run,
    )  # fmt: skip
    fill = _StoreFill(store, source, spec, reconstruction, camera, raw, progress, cancel)
    if replaces is None:
        before, lost, link = fill.run(client, workers, scheduler)
    else:  # the old store stays until the new run ends; a cancel, interrupt or error drops the new one
        try:
            before, lost, link = fill.run(client, workers, scheduler)
        except BaseException:
            discard_store(store)
            raise
        store = replace_store(store, replaces)
    return _result(store, before, store.records(), count=source.count, lost=lost, link=link)


@dataclass(frozen=True)
class _StoreFill:
    """Computing the frames of ``store`` not recorded as done (one run of :func:`reconstruct_video`)."""

    store: VideoStore
    source: FrameSource
    spec: ProjectorSpec
    reconstruction: ReconstructionOptions
    camera: CameraCalibration | None
    raw: RawFrameSpec | None
    progress: ProgressCallback | None
    cancel: CancelToken

    def run(
        self, client: Client | None, workers: int | None, scheduler: str | None
    ) -> tuple[dict[int, ChunkRecord], list[int], str | None]:
        """Run the chunks left to do; returns the records before, the lost chunks and the dashboard link."""
        store, source, progress = self.store, self.source, self.progress
        store.write_frames_stamp(source.stamp())
        before = store.records()
        done_before = {i: done_frames(record) for i, record in before.items()}
        chunks = store.chunks()
        run_id = uuid.uuid4().hex
        tasks = [
            ChunkTask(
                i, start, stop, source, self.spec, self.reconstruction, store, self.camera, run_id, self.raw
            )
            for i, (start, stop) in enumerate(chunks)
            if len(done_before.get(i, ())) < stop - start
        ]
        state = {"frames": sum(len(done) for done in done_before.values())}

        def on_record(record: ChunkRecord) -> None:
            state["frames"] += record["stop"] - record["start"] - len(done_before.get(record["chunk"], ()))
            if progress is not None:
                progress(state["frames"], source.count, f"chunk {record['chunk'] + 1}/{len(chunks)} done")

        with client_for(client, workers, scheduler) as active:
            link = dashboard_link(active)
            if progress is not None:
                progress(state["frames"], source.count, f"dashboard {link}" if link else "starting")
            lost = _run_chunks(tasks, active, on_record, self.cancel)
        return before, lost, link


def _done(records: Mapping[int, ChunkRecord]) -> set[int]:
    """Every frame ``records`` hold as done."""
    return {t for record in records.values() for t in done_frames(record)}


def _failures(records: Mapping[int, ChunkRecord]) -> dict[int, str]:
    """Frame -> error for every frame ``records`` hold as failed."""
    return {
        int(t): info["error"]
        for record in records.values()
        for t, info in record["frames"].items()
        if info["status"] == "failed"
    }


def _result(store: VideoStore, before: Mapping[int, ChunkRecord], after: Mapping[int, ChunkRecord], *,
            count: int, lost: list[int], link: str | None) -> VideoResult:  # fmt: skip
    """What the call did, from the chunk records before and after it (``lost``: chunks whose
    worker was lost, so their earlier failures were not tried again)."""
    skipped, done = _done(before), _done(after)
    failed = _failures(after)
    retried = _failures({i: record for i, record in before.items() if i not in lost})
    return VideoResult(
        store.path, count, tuple(sorted(done - skipped)), tuple(sorted(skipped)),
        dict(sorted(failed.items())), tuple(lost), link, tuple(sorted(retried)),
    )  # fmt: skip
