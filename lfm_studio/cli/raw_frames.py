"""``lfm-studio reconstruct --calibration calib.json``: raw camera frames made ready for the projector.

Order of the corrections (one dark subtraction, never two):

1. the calibration (``lfm-studio calibrate``) subtracts its dark frame pixel by pixel (or its
   dark level), replaces the defective pixels, divides by the flat field and resamples the
   frame onto the projector's lattice of ``pixels_per_lenslet`` pixels per lenslet
   (:func:`lfm_studio.engine.calibration.rectify_frame`); the result is in ADU above the dark
   level per rectified pixel;
2. the camera conversion then uses a baseline of 0 (the dark level is already gone), and the
   gain, read noise and quantum efficiency of ``--gain/--read-noise/--quantum-efficiency``, else the image's
   camera metadata, else the calibration's nominal design camera. ``--baseline`` is refused.

With ``--measured`` (a bead z-scan as the PSF) and a Fourier-LFM calibration, the bead frames
get the same corrections (step 1) before the PSF is prepared (:func:`calibrated_bead_psf`);
with a conventional-LFM calibration the combination is refused: a bead gives one PSF per
depth, and a conventional LFM's PSF changes with the position under the lenslet.

Register the options with :func:`add_raw_frame_arguments`.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

import torch


def add_raw_frame_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``--calibration`` and ``--lenslets`` options of ``reconstruct``."""
    group = parser.add_argument_group("raw camera frames (a calibration from 'lfm-studio calibrate')")
    group.add_argument(
        "--calibration",
        default=None,
        help="calibration JSON: the raw --image is dark-subtracted, defect-corrected, flat-fielded and "
        "rectified onto the PSF's lattice before reconstruction (its dark frame replaces --baseline)",
    )
    group.add_argument(
        "--lenslets",
        type=int,
        nargs=2,
        metavar=("NY", "NX"),
        default=None,
        help="with --calibration: rectify NY x NX lenslets around the frame centre (default: the "
        "calibration's lit block)",
    )


def load_raw_calibration(args: argparse.Namespace):
    """The calibration of ``--calibration`` (None without it); conflicting options are refused."""
    if args.calibration is None:
        if args.lenslets is not None:
            raise ValueError(
                f"--lenslets {args.lenslets[0]} {args.lenslets[1]} needs --calibration (it picks the "
                "rectified block of a raw frame). Fix: add --calibration calib.json or drop --lenslets."
            )
        return None
    from lfm_studio.engine.calibration import load_calibration

    if args.baseline is not None:
        raise ValueError(
            f"--baseline {args.baseline} with --calibration {args.calibration}: the calibration subtracts "
            "its dark frame, a second baseline would subtract the dark level twice. Fix: drop --baseline."
        )
    calibration = load_calibration(args.calibration)
    if args.measured and calibration.grid is not None:
        raise ValueError(
            f"--measured with --calibration {args.calibration}: a conventional-LFM calibration, but a bead "
            "z-scan gives one PSF per depth, and a conventional LFM has none (its PSF changes with the "
            "bead's position under its lenslet). Fix: drop --measured and simulate the PSF for the "
            "rectified frames ('lfm-studio calibrate ... --design-out rectified.json', then "
            "'lfm-studio simulate rectified.json --out psf.tif')."
        )
    return calibration


def calibrated_bead_psf(args: argparse.Namespace, stack, image, calibration):
    """``--measured`` with a Fourier-LFM ``--calibration``: the bead z-scan as the PSF of the frames.

    The scan, recorded on the same raw camera region as the frames, gets the frames' own
    corrections (dark frame, defective pixels, per-sub-image flat field); the calibration's
    dark level goes back on as a flat pedestal (the preparation estimates and removes the
    background itself, and a PSF stack holds no negative noise). It is then prepared
    (:func:`~lfm_studio.engine.bead_psf.prepare_measured_psf`: background, noise floor,
    centring, normalisation) and registered to the calibration's optical axis
    (:func:`~lfm_studio.engine.calibration.bead_scan.register_bead_psf`); without that the
    volume would be shifted by the unknown bead position.
    """
    from lfm_studio.engine.bead_psf import prepare_measured_psf
    from lfm_studio.engine.calibration import rectify_frame
    from lfm_studio.engine.calibration.bead_scan import register_bead_psf

    data = stack.data
    try:
        corrected = rectify_frame(data.detach().to("cpu", torch.float64), calibration)
    except ValueError as error:
        raise ValueError(
            f"--measured --psf {args.psf} with --calibration {args.calibration}: {error}"
        ) from error
    pedestal = (corrected + calibration.dark_level).clamp_min(0.0)
    stack = dataclasses.replace(stack, data=pedestal.to(dtype=data.dtype, device=data.device))
    sensor = tuple(image.data.shape[-2:])
    prepared = prepare_measured_psf(
        stack, sensor_shape=sensor, pixel_size=image.pixel_size, energy=args.psf_energy
    )
    return register_bead_psf(prepared, calibration)


def calibrated_camera(args: argparse.Namespace, metadata: dict[str, Any] | None, calibration):
    """The camera conversion for the dark-subtracted frames (baseline 0; see
    :func:`lfm_studio.engine.calibration.raw_camera.dark_subtracted_camera`)."""
    from lfm_studio.engine.calibration.raw_camera import dark_subtracted_camera

    return dark_subtracted_camera(
        calibration,
        metadata,
        gain=args.gain,
        read_noise=args.read_noise,
        quantum_efficiency=args.quantum_efficiency,
        source=f"calibration {args.calibration} (dark subtracted)",
    )


def rectified_image(args: argparse.Namespace, image, calibration, psf_shape: tuple[int, int], device: str):
    """``image`` (raw ADU) corrected and rectified with ``calibration``, on ``device`` in ``--dtype``;
    a shape that differs from the PSF's ``psf_shape`` is refused with both shapes and the fix."""
    from lfm_studio.engine.calibration import rectified_shape_fix, rectify_frame

    lenslets = None if args.lenslets is None else tuple(args.lenslets)
    try:
        frames = rectify_frame(image.data, calibration, lenslets=lenslets)
    except ValueError as error:
        raise ValueError(f"{args.image} with --calibration {args.calibration}: {error}") from error
    shape = tuple(frames.shape[-2:])
    if shape != tuple(psf_shape):
        n = calibration.pixels_per_lenslet
        what = (
            f"rectified to {shape} pixels ({shape[0] // n} x {shape[1] // n} lenslets of {n} px)"
            if calibration.grid is not None
            else f"corrected to {shape} pixels (a Fourier LFM frame is not resampled)"
        )
        raise ValueError(
            f"{args.image} {what} with {args.calibration}, but the PSF stack {args.psf} images "
            f"{tuple(psf_shape)} pixels. {rectified_shape_fix(calibration, tuple(psf_shape), '--lenslets {ny} {nx}')}"
        )
    data = frames.to(dtype=getattr(torch, args.dtype), device=device)
    return dataclasses.replace(image, data=data)
