"""``lfm-studio info DESIGN|PRESET [--json] [--measure] [--criterion C]``: a design's metrics and checks.

Prints the closed-form metrics (resolution, depth of field, field of view, views,
magnification) and the larval-zebrafish requirement checks of thesis section 2.3.1
as an aligned table, or as JSON with ``--json`` (units in key names). ``--measure``
also simulates a small PSF stack (Fourier LFM, per-lenslet model, a few depths) and
adds the values measured on it. ``--criterion`` picks the lateral resolution criterion of
the closed forms: ``rayleigh`` (0.61 lambda / NA, the thesis' section 3.3.1; default),
``abbe`` (lambda / (2 NA)) or ``sparrow`` (0.47 lambda / NA); the report names it.
Register with :func:`add_info_parser`.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import argparse
import sys
import time

from lfm_studio.engine.design import resolve_design
from lfm_studio.engine.performance import compute_design_metrics, format_metrics_table, measurement_psf
from lfm_studio.engine.performance.closed_forms import CRITERION_LABELS
from lfm_studio.engine.performance.psf_measures_stack import main_focus_depth, unmeasurable_reason


def add_info_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``info`` sub-command to ``subparsers`` (from ``parser.add_subparsers()``); returns it."""
    info = subparsers.add_parser(
        "info",
        help="design metrics (resolution, depth of field, field of view) and requirement checks",
        description=(
            "Closed-form design metrics of a light-field microscope and the larval-zebrafish "
            "requirements of the thesis (FoV >= 800 um, DoF >= 200 um, 3 x 3 x 5 um cells)."
        ),
    )
    info.add_argument("design", help="preset name (e.g. xlfm_cong2017) or path to a .json design file")
    info.add_argument(
        "--json", action="store_true", help="print JSON (units in key names) instead of a table"
    )
    info.add_argument(
        "--measure",
        action="store_true",
        help="also simulate a small PSF stack and measure FWHM, two-point resolution and depth of field "
        "(Fourier LFM only; seconds on a CPU)",
    )
    info.add_argument(
        "--criterion",
        choices=sorted(CRITERION_LABELS),
        default="rayleigh",
        help="lateral resolution criterion of the closed forms: "
        + "; ".join(f"{name}: {label}" for name, label in CRITERION_LABELS.items())
        + " (default rayleigh, as in the thesis section 3.3.1); it sets the diffraction term only: "
        "a value set by the sampling (pixels, or a conventional LFM's lenslet pitch) is labelled so",
    )
    info.set_defaults(handler=run_info)
    return info


def run_info(args: argparse.Namespace) -> int:
    """Handler of ``info``: print the report; 0 on success (a design that cannot be read raises)."""
    design = resolve_design(args.design)  # a refusal: cli.main prints it, exit 2
    psf, focus = None, None
    if args.measure:
        why = unmeasurable_reason(design)
        if why is not None:
            print(
                f"lfm-studio info: {why}; showing the closed forms only "
                "(lfm-studio resolution measures a resolution by reconstructing two points).",
                file=sys.stderr,
            )
        else:
            start = time.perf_counter()
            print("lfm-studio info: simulating a small PSF stack ...", file=sys.stderr)
            psf, focus = measurement_psf(design), main_focus_depth(design)
            print(
                f"lfm-studio info: {len(psf.depths)} depths on {psf.data.shape[-2]} x {psf.data.shape[-1]} pixels "
                f"in {time.perf_counter() - start:.1f} s",
                file=sys.stderr,
            )
    metrics = compute_design_metrics(design, psf=psf, focus_depth=focus, criterion=args.criterion)
    print(metrics.to_json() if args.json else format_metrics_table(metrics))
    return 0
