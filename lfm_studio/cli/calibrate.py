"""``lfm-studio calibrate --radiometry R.tif [--dark D.tif] --design DESIGN --out calib.json [--design-out D.json]``.

Measures the lenslet grid (conventional LFM) or the sub-image centres (Fourier LFM), the
dark level, defective pixels and the flat field from a radiometry frame, and writes a
versioned JSON calibration that reconstruction accepts beside a raw frame (with ``--dark``,
the dark frame is stored next to it as ``<out stem>.dark.<hash>.npz``, named in the JSON). A TIFF stack
of several exposures is averaged into one frame. ``--design-out`` also writes the design to
simulate the PSF with for ``reconstruct --calibration`` (conventional:
:func:`~lfm_studio.engine.calibration.rectified_design`; Fourier:
:func:`~lfm_studio.engine.calibration.fitted_design`). Register with :func:`add_calibrate_parser`.
"""

from __future__ import annotations

import argparse

from lfm_studio.cli.interrupts import watching
from lfm_studio.cli.progress import progress_bar


def add_calibrate_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``calibrate`` sub-command to ``subparsers``; returns it."""
    parser = subparsers.add_parser(
        "calibrate",
        help="measure the lenslet grid, dark level, hot pixels and flat field from a radiometry frame",
        description=(
            "Calibrate a light-field microscope from a radiometry frame (a uniform fluorescent slide "
            "imaged through the MLA) and an optional dark frame; writes a JSON calibration."
        ),
    )
    parser.add_argument("--radiometry", required=True, help="radiometry frame (TIFF; a stack is averaged)")
    parser.add_argument("--dark", default=None, help="dark frame, same exposure, light blocked (TIFF)")
    parser.add_argument(
        "--design", required=True, help="preset name or .json design file (the nominal optics)"
    )
    parser.add_argument("--out", required=True, help="calibration file to write (.json)")
    parser.add_argument(
        "--design-out",
        default=None,
        help="also write the design to simulate the PSF with (.json): conventional LFM, the nominal optics "
        "on the rectified frames' sensor; Fourier LFM, the lenslets at their measured centres",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    parser.set_defaults(handler=run_calibrate)
    return parser


def _save_psf_design(args: argparse.Namespace, design, calibration) -> None:
    """Write ``--design-out``: the design whose PSF matches what ``reconstruct --calibration`` feeds it."""
    from lfm_studio.engine.calibration import fitted_design, rectified_design
    from lfm_studio.engine.design import save_design

    psf_design = (
        rectified_design(design, calibration)
        if calibration.grid is not None
        else fitted_design(design, calibration)
    )
    save_design(psf_design, args.design_out, overwrite=args.overwrite)
    ny, nx = psf_design.camera.pixel_count
    print(f"wrote {args.design_out}: simulate the PSF with it (sensor {ny} x {nx} px)")


@watching("out", "design_out")
def run_calibrate(args: argparse.Namespace) -> int:
    """Handler of ``calibrate``: 0 on success (errors propagate to ``cli.main``, which prints them)."""
    from lfm_studio.engine.calibration import calibrate, save_calibration
    from lfm_studio.engine.calibration.frame_files import read_frame
    from lfm_studio.engine.design import resolve_design
    from lfm_studio.engine.io.file_checks import check_output

    inputs = (args.radiometry, args.dark)
    out = check_output(args.out, overwrite=args.overwrite, inputs=inputs)
    if args.design_out is not None:
        check_output(args.design_out, overwrite=args.overwrite, inputs=inputs, flag="--design-out")
    design = resolve_design(args.design, "--design")
    pixel = design.camera.pixel_pitch
    radiometry = read_frame("--radiometry", args.radiometry, pixel)
    dark = None if args.dark is None else read_frame("--dark", args.dark, pixel)
    with progress_bar(f"calibration ({design.kind})") as progress:
        calibration = calibrate(radiometry, design, dark=dark, progress=progress)
    save_calibration(calibration, out, overwrite=args.overwrite)
    if args.design_out is not None:
        _save_psf_design(args, design, calibration)
    summary = calibration.summary()
    if calibration.grid is not None:
        py, px = summary["pitch_yx_px"]
        print(
            f"lenslet pitch {py:.4f} x {px:.4f} px, rotation {summary['rotation_deg']:.4f} deg, "
            f"{summary['lenslets']} lenslets ({summary['flagged']} flagged), "
            f"RMS residual {summary['rms_residual_px']:.4f} px"
        )
    else:
        print(
            f"{summary['sub_images']} sub-images ({summary['flagged']} flagged), scale {summary['scale']:.5f}, "
            f"rotation {summary['rotation_deg']:.4f} deg, RMS residual {summary['rms_residual_px']:.4f} px"
        )
    level = calibration.dark_level
    print(f"dark level {level:.6g} ADU, {summary['defect_pixels']} defective pixels; wrote {out}")
    return 0
