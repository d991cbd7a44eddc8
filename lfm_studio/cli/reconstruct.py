"""``lfm-studio reconstruct``: volumes from light-field images.

``reconstruct`` reads a PSF stack (simulated, or bead-measured with ``--measured``) and
a camera image (``(Y, X)``, or frames ``(T, Y, X)`` reconstructed one by one into a
``(T, Z, Y, X)`` volume) and writes the volume with its voxel size and depths. Camera
counts (ADU) are first turned into photons, ``max((ADU - baseline) / gain + c, 0) / QE``
with the camera's noise floor ``c`` modelled as background
(:func:`lfm_studio.engine.io.counts_to_photons`), from the image's camera metadata
(``lfm-studio image`` writes it), from ``--baseline/--gain/--read-noise/--quantum-efficiency``, or with a
baseline estimated from the darkest pixels and a warning; the volume is then in photons
per voxel, the unit of ``image --truth``. A volume that comes out all zero, constant or
NaN/Inf is refused (exit 5) and not written. With ``--calibration`` (from ``lfm-studio
calibrate``) a raw camera frame is first corrected and rectified onto the projector's lattice
(:mod:`lfm_studio.cli.raw_frames`); the dark level is then the calibration's, not the camera's
baseline. The file is written once, atomically, after
the last frame: a failed or interrupted run leaves no partial output. Register it with
:func:`add_reconstruct_parsers`; its quality is scored by ``lfm-studio metrics``
(:mod:`lfm_studio.cli.metrics`).
"""

from __future__ import annotations

import argparse
import math
import sys

import torch

from lfm_studio.cli.input_files import require_file
from lfm_studio.cli.interrupts import watching
from lfm_studio.cli.method_options import add_method_arguments, method_options
from lfm_studio.cli.progress import progress_bar
from lfm_studio.cli.raw_frames import (
    add_raw_frame_arguments,
    calibrated_bead_psf,
    calibrated_camera,
    load_raw_calibration,
    rectified_image,
)
from lfm_studio.cli.simulate import allow_negative_values, parse_depths, resolve_device
from lfm_studio.cli.video import add_video_arguments, is_video_output, run_video
from lfm_studio.engine.reconstruct import registry
from lfm_studio.engine.simulation import depth_grid

_READ_FLAGS = {
    "pixel_size": "--pixel-size-um (sensor pixel pitch)",
    "magnification": "--magnification",
    "wavelength": "--wavelength-nm",
    "depths": "--depths=START:STOP:STEP (um, one depth per slice)",
}


def _quantum_efficiency(text: str) -> float:
    """``--quantum-efficiency``: photo-electrons per detected photon, a fraction in (0, 1]."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 < value <= 1.0:  # NaN fails too
        raise argparse.ArgumentTypeError(
            f"--quantum-efficiency must be a fraction 0 < QE <= 1 (photo-electrons per photon); got {text!r}. "
            "Fix: give the camera's QE at the emission wavelength, e.g. --quantum-efficiency 0.8 for 80 %."
        )
    return value


def _depth_list(depths_um: tuple[float, float, float] | None) -> tuple[float, ...] | None:
    """START:STOP:STEP in um -> depths in metres (STOP included when on the grid)."""
    return None if depths_um is None else depth_grid(depths_um, "--depths")


def _read_psf(args: argparse.Namespace, device: str):
    from lfm_studio.engine.io import MissingMetadataError, read_psf_stack

    um, nm = 1e-6, 1e-9
    try:
        return read_psf_stack(
            args.psf,
            pixel_size=None if args.pixel_size_um is None else args.pixel_size_um * um,
            magnification=args.magnification,
            wavelength=None if args.wavelength_nm is None else args.wavelength_nm * nm,
            depths=_depth_list(args.depths),
            dtype=getattr(torch, args.dtype),
            device=device,
        )
    except MissingMetadataError as error:
        flags = ", ".join(_READ_FLAGS.get(name, name) for name in error.missing)
        raise ValueError(f"{args.psf} has no {', '.join(error.missing)}. Fix: pass {flags}.") from error


def _read_frames(args: argparse.Namespace, psf_pixel: float, device: str):
    from lfm_studio.engine.io import MissingMetadataError, read_image

    if args.calibration is not None:  # rectified onto the PSF's lattice: the PSF's pixels
        return read_image(args.image, pixel_size=psf_pixel, dtype=torch.float64, device="cpu")
    try:
        return read_image(args.image, dtype=getattr(torch, args.dtype), device=device)
    except MissingMetadataError:
        print(
            f"lfm-studio reconstruct: {args.image} has no pixel size; taking the PSF's {psf_pixel * 1e6:g} um.",
            file=sys.stderr,
        )
        return read_image(args.image, pixel_size=psf_pixel, dtype=getattr(torch, args.dtype), device=device)


def _prepare_stack(args: argparse.Namespace, stack, image):
    """The PSF stack on the image's sampling: measured stacks are prepared, simulated ones are checked."""
    from lfm_studio.engine.bead_psf import prepare_measured_psf

    sensor = tuple(image.data.shape[-2:])
    if args.measured:
        return prepare_measured_psf(
            stack, sensor_shape=sensor, pixel_size=image.pixel_size, energy=args.psf_energy
        )
    if (
        stack.data.ndim == 3
        and args.calibration is None
        and not math.isclose(stack.camera_pixel_size, image.pixel_size, rel_tol=1e-6)
    ):
        raise ValueError(
            f"{args.image} has {image.pixel_size * 1e6:g} um pixels but the PSF stack {args.psf} has "
            f"{stack.camera_pixel_size * 1e6:g} um pixels. Fix: pass --measured to resample the PSF to the image, "
            "or simulate the PSF for this camera."
        )
    return stack


def _either(names: list[str]) -> str:
    """``["a", "b", "c"]`` as ``"a, b or c"`` (a refusal's choices)."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"


def _reconstruct_frame(
    method, options: dict, projector, frame: torch.Tensor, floor: float, report
) -> torch.Tensor:
    """One frame in photons; ``floor`` is the camera's noise floor it carries (photons per pixel),
    modelled as background on top of ``--background``."""
    return method(projector, frame, {**options, "background": options["background"] + floor}, report)


def _photons(args: argparse.Namespace, image, raw_calibration=None):
    """The frames in photons, the noise floor they carry (photons per pixel) and the calibration used
    (warnings printed for what was assumed); ``raw_calibration``: the frames are dark-subtracted."""
    from lfm_studio.engine.io import counts_to_photons, resolve_calibration

    if raw_calibration is not None:
        calibration, notes = calibrated_camera(args, image.metadata, raw_calibration), []
    else:
        calibration, notes = resolve_calibration(
            image.metadata,
            image.data,
            baseline=args.baseline,
            gain=args.gain,
            read_noise=args.read_noise,
            quantum_efficiency=args.quantum_efficiency,
        )
    for note in notes:
        print(f"lfm-studio reconstruct: warning: {args.image}: {note}", file=sys.stderr)
    photons, floor = counts_to_photons(image.data, calibration, name=str(args.image))
    return photons, floor, calibration


@watching("out")  # a video store says more itself (cli/video.py)
def run_reconstruct(args: argparse.Namespace) -> int:
    """Handler of ``reconstruct``: read, reconstruct every frame, write once; 0 on success."""
    from lfm_studio.engine.io import check_output, write_volume
    from lfm_studio.engine.reconstruct import check_reconstruction
    from lfm_studio.engine.simulation import imaging_setup

    require_file("--psf", args.psf, "a PSF stack TIFF (from 'lfm-studio simulate', or beads with --measured)")
    require_file("--calibration", args.calibration, "a calibration .json from 'lfm-studio calibrate'")
    if is_video_output(args.out):  # --out NAME.ome.zarr: a video on Dask (cli/video.py)
        return run_video(args)
    require_file("--image", args.image, "a light-field image TIFF, (Y, X) or frames (T, Y, X)")
    inputs = [args.psf, args.image] + ([] if args.calibration is None else [args.calibration])
    check_output(args.out, overwrite=args.overwrite, inputs=inputs, tiff=True)  # (a .zarr is a video)
    method, options = method_options(args)
    device = resolve_device(args.device)
    if device not in method.devices:
        raise ValueError(
            f"--method {method.name} runs on {' or '.join(method.devices)}; got --device {device}. "
            f"Fix: --device {method.devices[0]}."
        )
    raw_calibration = load_raw_calibration(args)
    stack = _read_psf(args, device)
    image = _read_frames(args, stack.pixel_size, device)
    if raw_calibration is not None and args.measured:  # the bead z-scan gets the frames' corrections
        stack = calibrated_bead_psf(args, stack, image, raw_calibration)
    else:
        stack = _prepare_stack(args, stack, image)
    fov = None if args.field_of_view_um is None else args.field_of_view_um * 1e-6
    setup = imaging_setup(stack, field_of_view=fov)
    if method.name == "learned" and isinstance(options.get("model"), str):
        from lfm_studio.engine.learned import check_checkpoint_for_stack  # the design hash and depths, too

        check_checkpoint_for_stack(str(options["model"]), stack, setup)
    if not method.supports(setup.projector):
        others = _either(registry.supporting(setup.projector))
        raise ValueError(
            f"--method {args.method} needs a laterally shift-invariant (Fourier LFM) PSF stack; {args.psf} is a "
            f"conventional-LFM pattern stack. Fix: use --method {others}."
        )
    if raw_calibration is not None:
        image = rectified_image(args, image, raw_calibration, tuple(setup.projector.image_shape), device)
    elif tuple(image.data.shape[-2:]) != tuple(setup.projector.image_shape):
        raise ValueError(
            f"{args.image} has frames of {tuple(image.data.shape[-2:])} pixels but the PSF stack {args.psf} "
            f"images {tuple(setup.projector.image_shape)} pixels. Fix: use the PSF simulated for this camera, "
            "or --measured to crop/resample a measured one; raw frames of a real microscope (lenslet grid "
            "off the pixel lattice) need --calibration calib.json (docs/calibration.md)."
        )
    photons, floor, calibration = _photons(args, image, raw_calibration)
    frames = photons if photons.ndim == 3 else photons[None]
    count, steps = frames.shape[0], method.steps(options)
    volumes = []  # Ctrl+C: cli.main exits 130; nothing is written before the last frame
    with progress_bar(f"{args.method} ({count} frame{'s' if count > 1 else ''})") as progress:
        for t, frame in enumerate(frames):

            def report(done: int, total: int, message: str, t: int = t) -> None:
                progress(t * steps + min(done, steps), count * steps, f"frame {t + 1}/{count}: {message}")

            report(0, steps, "starting")
            volume = _reconstruct_frame(method, options, setup.projector, frame, floor, report).detach().cpu()
            what = f"the {args.method} reconstruction of {args.image}" + (
                f" (frame {t})" if count > 1 else ""
            )
            volumes.append(check_reconstruction(volume, what=what))
            report(steps, steps, "done")
    volume = torch.stack(volumes) if image.data.ndim == 3 else volumes[0]
    metadata = {
        "method": args.method,
        **options,  # the method's options (iterations, snr, ...), background = --background
        "noise_floor_photons": floor,
        "psf": str(args.psf),
        "image": str(args.image),
        "measured_psf": bool(args.measured),
        "units": calibration.volume_units,
        "camera": calibration.to_dict(),
        "calibration": None if args.calibration is None else str(args.calibration),
    }
    write_volume(
        args.out,
        volume,
        voxel_size=setup.voxel_size,
        depths=stack.depths,
        metadata=metadata,
        overwrite=args.overwrite,
    )
    voxel = ", ".join(f"{v * 1e6:.4g}" for v in setup.voxel_size)
    print(f"wrote {args.out}: volume {tuple(volume.shape)}, voxels (dz, dy, dx) = ({voxel}) um")
    return 0


def add_reconstruct_parsers(subparsers: argparse._SubParsersAction) -> None:
    """Register ``reconstruct`` on ``subparsers`` (from ``parser.add_subparsers()``)."""
    rec = allow_negative_values(
        subparsers.add_parser(
            "reconstruct",
            help="reconstruct a volume from a light-field image and a PSF stack",
            description="Reconstruction with any registered method (Richardson-Lucy, plain or accelerated, "
            "Wiener, Tikhonov, ...: see --method). A (T, Y, X) image is reconstructed frame by frame into a (T, Z, Y, X) volume. "
            "Camera counts are converted to photons first, max((ADU - baseline) / gain + c, 0) / QE, where c, "
            "the camera's read-noise floor, keeps dark pixels from being clipped and is modelled as background; "
            "the camera comes from the image's metadata, --baseline/--gain, "
            "or an estimated baseline (with a warning). Output: photons per voxel, the unit of "
            "'lfm-studio image --truth'. An all-zero, constant or NaN/Inf result is refused (exit 5).",
        )
    )
    rec.add_argument(
        "--psf", required=True, help="PSF stack TIFF (from 'lfm-studio simulate', or beads with --measured)"
    )
    rec.add_argument("--image", required=True, help="light-field image TIFF, (Y, X) or frames (T, Y, X)")
    rec.add_argument(
        "--out", required=True, help="output volume TIFF (ImageJ hyperstack with voxel size and depths)"
    )
    add_method_arguments(rec)
    rec.add_argument(
        "--background",
        type=float,
        default=0.0,
        help="extra background in photons per pixel after the camera baseline is removed, e.g. "
        "out-of-focus light (default 0; the baseline is --baseline)",
    )
    camera = rec.add_argument_group("camera counts of an image without lfm_studio camera metadata")
    camera.add_argument(
        "--baseline",
        type=float,
        default=None,
        help="camera offset in ADU (default: the image's metadata, else estimated from the darkest 1 %% "
        "of the pixels, with a warning)",
    )
    camera.add_argument(
        "--gain",
        type=float,
        default=None,
        help="conversion gain in ADU per photo-electron (default: the image's metadata, else 1 with a "
        "warning: the volume is then in ADU above the baseline)",
    )
    camera.add_argument(
        "--quantum-efficiency",
        type=_quantum_efficiency,
        default=None,
        metavar="QE",
        help="photo-electrons per photon, 0 < QE <= 1 (default: the image's metadata, else 1: with "
        "--gain and no metadata the volume then counts photo-electrons, low by 1/QE in photons)",
    )
    camera.add_argument(
        "--read-noise",
        type=float,
        default=None,
        help="camera read noise in electrons rms (default: the image's metadata, else 0); sets the noise "
        "floor added before clipping at 0 and modelled as background",
    )
    rec.add_argument(
        "--field-of-view-um",
        type=float,
        default=None,
        help="lateral volume size in um (default: the design's, else a quarter of the sensor)",
    )
    add_raw_frame_arguments(rec)
    rec.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    rec.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    rec.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    measured = rec.add_argument_group("measured (bead) PSF stacks, and PSF metadata a TIFF lacks")
    measured.add_argument(
        "--measured",
        action="store_true",
        help="background-subtract, centre, resample and normalise the PSF stack",
    )
    measured.add_argument(
        "--psf-energy", type=float, default=1.0, help="mean per-depth sum after normalising (default 1)"
    )
    measured.add_argument(
        "--pixel-size-um", type=float, default=None, help="sensor pixel pitch of the PSF TIFF (um)"
    )
    measured.add_argument(
        "--magnification", type=float, default=None, help="sample-to-sensor magnification of the PSF"
    )
    measured.add_argument(
        "--wavelength-nm", type=float, default=None, help="emission wavelength of the PSF (nm)"
    )
    measured.add_argument(
        "--depths",
        type=parse_depths,
        default=None,
        help="START:STOP:STEP in um, one depth per slice, e.g. --depths -20:20:5",
    )
    add_video_arguments(rec)
    rec.set_defaults(handler=run_reconstruct)
