"""``lfm-studio reconstruct --out run.ome.zarr``: a video, frame by frame, on Dask, into OME-Zarr.

An output ending in ``.zarr`` turns ``reconstruct`` into a video run
(:func:`lfm_studio.engine.batch.reconstruct_video`): the frames (``--image``: a multi-page
TIFF, a folder of TIFFs or a Zarr array) are read lazily, chunk by chunk, by ``--workers N``
one-thread processes (a LocalCluster; 1: in this process) or by the cluster at
``--scheduler tcp://host:8786``; each finished chunk is recorded in the store, so ``--resume``
(after a crash, Ctrl+C or failed frames) computes only the missing frames and those that failed.
Camera counts become photons per frame as in the TIFF path (metadata or
``--baseline/--gain/--read-noise/--quantum-efficiency``); raw frames with ``--calibration calib.json`` (and
``--lenslets``) are corrected and rectified frame by frame first, as in the TIFF path
(:mod:`lfm_studio.cli.raw_frames`). Needs the ``scale`` extra (``pip install "lfm-studio[scale]"``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from lfm_studio.cli.interrupts import on_interrupt, previous_store_unchanged
from lfm_studio.cli.progress import progress_bar

_NOT_FOR_VIDEO = {  # options of the TIFF path a video run does not take, and why
    "measured": "--measured (prepare the bead PSF once with the TIFF path, then pass it as --psf)",
    "pixel_size_um": "--pixel-size-um (a video's PSF stack must carry its metadata)",
    "magnification": "--magnification (a video's PSF stack must carry its metadata)",
    "wavelength_nm": "--wavelength-nm (a video's PSF stack must carry its metadata)",
    "depths": "--depths (a video's PSF stack must carry its metadata)",
}


SHAPE_FIX = (
    "raw frames of a real microscope need --calibration calib.json (from `lfm-studio calibrate`); "
    "other frames need the PSF simulated for this camera (--psf from `lfm-studio simulate DESIGN`)."
)
"""The CLI's fix for frames that are not the pixels the PSF images (no ``--calibration`` given)."""


def is_video_output(out: Any) -> bool:
    """True when ``--out`` names an OME-Zarr store (``*.zarr``: the rule reconstruct_video enforces)."""
    from lfm_studio.engine.io.file_checks import names_zarr_store

    return names_zarr_store(str(out))


def add_video_arguments(parser: argparse.ArgumentParser) -> None:
    """The video options of ``reconstruct`` (used with ``--out NAME.ome.zarr``)."""
    group = parser.add_argument_group("videos to OME-Zarr (--out NAME.ome.zarr; docs/scale_out.md)")
    group.add_argument(
        "--workers", type=int, default=None, metavar="N",
        help="worker processes of a local Dask cluster, one thread each (default 1: in this process)",
    )  # fmt: skip
    group.add_argument(
        "--scheduler", default=None, metavar="ADDRESS",
        help="run on the Dask cluster at this address, e.g. tcp://host:8786 (its workers must see the files)",
    )  # fmt: skip
    group.add_argument(
        "--resume", action="store_true",
        help="continue a run into the same store: only frames missing or recorded as failed are computed",
    )  # fmt: skip
    group.add_argument("--chunk-frames", type=int, default=4, metavar="N", help="frames per task (default 4)")
    group.add_argument(
        "--frame-interval-s", type=float, default=None, metavar="SECONDS",
        help="time between frames, for the t axis scale (default 1 s, recorded as assumed)",
    )  # fmt: skip


def _camera(args: argparse.Namespace, source, raw_calibration) -> Any:
    """The camera calibration of the frames (warnings printed for what was assumed); after a
    ``--calibration`` the dark-subtracted camera (baseline 0)."""
    from lfm_studio.cli.raw_frames import calibrated_camera
    from lfm_studio.engine.batch.camera import tiff_metadata, video_camera

    if raw_calibration is not None:
        return calibrated_camera(args, tiff_metadata(source.path), raw_calibration)
    calibration, notes = video_camera(
        source,
        baseline=args.baseline,
        gain=args.gain,
        read_noise=args.read_noise,
        quantum_efficiency=args.quantum_efficiency,
    )
    for note in notes:
        print(f"lfm-studio reconstruct: warning: {args.image}: {note}", file=sys.stderr)
    return calibration


def _store_kept(out: str, count: int, *, replacing: bool = False) -> str | None:
    """What an interrupted video run kept in its store ``out`` of ``count`` frames (None: no store;
    ``replacing``: an ``--overwrite`` of an existing store, which the engine leaves unchanged)."""
    from lfm_studio.engine.batch.store import frame_report

    if replacing:
        return previous_store_unchanged(out)
    if not Path(out).expanduser().is_dir():
        return None
    report = frame_report(Path(out).expanduser())
    done = count - len(report.failed) - len(report.missing)
    return (
        f"{done} of {count} frames are in {out} (each finished chunk is recorded). "
        "Fix: run the same command with --resume to compute only the others."
    )


def _refuse_unsupported(args: argparse.Namespace) -> None:
    for name, flag in _NOT_FOR_VIDEO.items():
        if getattr(args, name, None):
            raise ValueError(f"{flag} is not supported with an OME-Zarr --out. Fix: drop it.")
    if args.device != "cpu":
        raise ValueError(
            f"--device {args.device} is not supported with an OME-Zarr --out yet. Fix: --device cpu."
        )


def run_video(args: argparse.Namespace) -> int:
    """``reconstruct`` into an OME-Zarr store; 0 on success, refusals raise (cli.main maps them)."""
    from lfm_studio.engine.batch.extras import MissingExtraError, require_scale
    from lfm_studio.engine.reconstruct.result_check import ReconstructionRejectedError

    try:
        require_scale()
    except MissingExtraError as error:  # a usage error here (exit 2), not a traceback
        raise ValueError(f"--out {args.out} (OME-Zarr): {error}") from error
    from lfm_studio.cli.method_options import method_options
    from lfm_studio.cli.raw_frames import load_raw_calibration
    from lfm_studio.engine.batch import client_for, dashboard_link, open_frames, reconstruct_video

    _refuse_unsupported(args)
    method, options = method_options(args)
    raw_calibration = load_raw_calibration(args)  # refuses --baseline and --lenslets misuse
    source = open_frames(args.image)
    camera = _camera(args, source, raw_calibration)
    lenslets = None if args.lenslets is None else tuple(args.lenslets)
    fov = None if args.field_of_view_um is None else args.field_of_view_um * 1e-6
    replacing = bool(args.overwrite) and Path(args.out).expanduser().exists()
    with client_for(None, args.workers, args.scheduler) as client:
        link = dashboard_link(client)
        if link:
            print(f"lfm-studio reconstruct: Dask dashboard: {link}", file=sys.stderr)
        with (
            progress_bar(f"{args.method} ({source.count} frames)") as bar,
            on_interrupt(lambda: _store_kept(args.out, source.count, replacing=replacing)),
        ):
            result = reconstruct_video(
                source, args.psf, method=method.name, options=options, output=args.out, resume=args.resume,
                overwrite=args.overwrite,
                client=client, chunk_frames=args.chunk_frames, frame_interval_s=args.frame_interval_s,
                camera=camera, field_of_view=fov, dtype=args.dtype, calibration=args.calibration, shape_fix=SHAPE_FIX,
                lenslets=lenslets,
                progress=lambda done, total, message: bar(done, total, message),
            )  # fmt: skip
    print(
        f"wrote {result.path}: {result.frame_count} frames ({len(result.computed)} computed now, "
        f"{len(result.skipped)} done before)"
    )
    if result.retried:
        print(f"lfm-studio reconstruct: {result.retried_note()}", file=sys.stderr)
    if result.unfinished:
        print(f"lfm-studio reconstruct: chunks {list(result.unfinished)} were lost with their worker; "
              "run again with --resume to finish them.", file=sys.stderr)  # fmt: skip
    if result.failed:
        listed = "; ".join(f"frame {t}: {error}" for t, error in result.failed.items())
        raise ReconstructionRejectedError(
            f"{len(result.failed)} frame(s) failed after a retry ({listed}). The other frames are in "
            f"{result.path}; failures are recorded in its lfm_studio_status. Fix: check those frames, "
            "then run again with --resume (only the failed frames are computed again)."
        )
    return 0
