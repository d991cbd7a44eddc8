"""``lfm-studio reconstruct --calibration calib.json``: raw camera frames made ready for the projector.

Order of the corrections (one dark subtraction, never two):

1. the calibration (``lfm-studio calibrate``) subtracts its dark frame pixel by pixel (or its
   dark level), replaces the defective pixels, divides by the flat field and resamples the
   frame onto the projector's lattice of ``pixels_per_lenslet`` pixels per lenslet
   (:func:`lfm_studio.engine.calibration.rectify_frame`); the result is in ADU above the dark
   level per rectified pixel;
2. the camera conversion then uses a baseline of 0 (the dark level is already gone), and the
   gain, quantum efficiency and read noise of ``--gain/--read-noise``, else the image's
   camera metadata, else the calibration's nominal design camera. ``--baseline`` is refused.

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
    if args.measured:
        raise ValueError(
            f"--measured with --calibration {args.calibration}: a bead PSF measured on the raw camera is not "
            "rectified yet. Fix: simulate the PSF for the rectified frames ('lfm-studio calibrate ... "
            "--design-out rectified.json', then 'lfm-studio simulate rectified.json --out psf.tif')."
        )
    return load_calibration(args.calibration)


def calibrated_camera(args: argparse.Namespace, metadata: dict[str, Any] | None, calibration):
    """The camera conversion for the dark-subtracted frames (baseline 0; see
    :func:`lfm_studio.engine.calibration.raw_camera.dark_subtracted_camera`)."""
    from lfm_studio.engine.calibration.raw_camera import dark_subtracted_camera

    return dark_subtracted_camera(
        calibration,
        metadata,
        gain=args.gain,
        read_noise=args.read_noise,
        source=f"calibration {args.calibration} (dark subtracted)",
    )


def _fix(calibration, psf_shape: tuple[int, int]) -> str:
    """How to make the PSF and the rectified frames agree."""
    fix = (
        "Fix: simulate the PSF for these frames ('lfm-studio calibrate --radiometry ... --design-out "
        "rectified.json', then 'lfm-studio simulate rectified.json --out psf.tif')"
    )
    n = calibration.pixels_per_lenslet
    if n and psf_shape[0] % n == 0 and psf_shape[1] % n == 0:
        fix += f", or pass --lenslets {psf_shape[0] // n} {psf_shape[1] // n} to match this PSF"
    return fix + "."


def rectified_image(args: argparse.Namespace, image, calibration, psf_shape: tuple[int, int], device: str):
    """``image`` (raw ADU) corrected and rectified with ``calibration``, on ``device`` in ``--dtype``;
    a shape that differs from the PSF's ``psf_shape`` is refused with both shapes and the fix."""
    from lfm_studio.engine.calibration import rectify_frame

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
            f"{tuple(psf_shape)} pixels. {_fix(calibration, tuple(psf_shape))}"
        )
    data = frames.to(dtype=getattr(torch, args.dtype), device=device)
    return dataclasses.replace(image, data=data)
