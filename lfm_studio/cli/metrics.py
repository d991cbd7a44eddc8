"""``lfm-studio metrics``: the quality of a reconstructed volume against its ground truth.

Prints NCC and (for point and bead phantoms) the F1 score of matched local maxima
first, then PSNR and SSIM on a stated normalisation; every score sits beside the
score of the all-zero and the constant volume on the same truth (its "floors") and
the margin over the best floor, so a sparse phantom's flattering PSNR cannot pass for
a reconstruction. ``--json`` prints the same numbers. Register with :func:`add_metrics_parser`.
"""

from __future__ import annotations

import argparse
import json
import math
from typing import TYPE_CHECKING

import torch

from lfm_studio.cli.input_files import require_file
from lfm_studio.engine.image_quality.basic import NORMALIZATIONS

if TYPE_CHECKING:
    from lfm_studio.engine.image_quality import PeakMatch


def _read_for_metrics(path: str):
    """``(volume, voxel sizes known)``; a TIFF without voxel sizes is read with 1 m placeholders."""
    from lfm_studio.engine.io import MissingMetadataError, read_volume

    try:
        return read_volume(path, dtype=torch.float64), True
    except MissingMetadataError:  # metrics need no voxel size; only the consistency check is skipped
        return read_volume(path, voxel_size=(1.0, 1.0, 1.0), dtype=torch.float64), False


def _check_grids(args: argparse.Namespace, truth, estimate, both_known: bool) -> None:
    if truth.data.ndim != 3:
        raise ValueError(
            f"--truth {args.truth} must be one volume (Z, Y, X); got shape {tuple(truth.data.shape)}."
        )
    if tuple(estimate.data.shape[-3:]) != tuple(truth.data.shape):
        raise ValueError(
            f"--estimate {args.estimate} has shape {tuple(estimate.data.shape)} but --truth {args.truth} has "
            f"{tuple(truth.data.shape)} (Z, Y, X). Fix: reconstruct on the truth's grid (same PSF depths and "
            "field of view)."
        )
    if both_known:
        for a, b in zip(truth.voxel_size, estimate.voxel_size, strict=True):
            if not math.isclose(a, b, rel_tol=1e-6):
                raise ValueError(
                    f"--truth {args.truth} has voxels {tuple(v * 1e6 for v in truth.voxel_size)} um but "
                    f"--estimate {args.estimate} has {tuple(v * 1e6 for v in estimate.voxel_size)} um. "
                    "Fix: compare volumes on the same grid."
                )


def _peak_settings(args: argparse.Namespace, truth, truth_known: bool):
    """``(match peaks?, PeakOptions)`` from the flags; ``auto`` = a bead phantom or a point-like truth."""
    from lfm_studio.engine.image_quality import PeakOptions, looks_point_like

    if not 0.0 <= args.peak_threshold < 1.0:
        raise ValueError(
            f"--peak-threshold must be a fraction of the volume's maximum in [0, 1); got {args.peak_threshold}."
        )
    if not (math.isfinite(args.tolerance_voxels) and args.tolerance_voxels > 0):
        raise ValueError(f"--tolerance-voxels must be a number > 0; got {args.tolerance_voxels}.")
    if args.tolerance_um is not None:
        if not (math.isfinite(args.tolerance_um) and args.tolerance_um > 0):
            raise ValueError(f"--tolerance-um must be a length > 0 in um; got {args.tolerance_um}.")
        if not truth_known:
            raise ValueError(
                f"--tolerance-um needs voxel sizes, and --truth {args.truth} has none. "
                "Fix: use --tolerance-voxels, or write the truth with its voxel size."
            )
    options = PeakOptions(
        threshold=args.peak_threshold, tolerance=args.tolerance_voxels, tolerance_um=args.tolerance_um
    )
    if args.peaks == "auto":
        use = truth.metadata.get("phantom") == "beads" or looks_point_like(truth.data)
    else:
        use = args.peaks == "on"
    return use, options


def peaks_line(p: PeakMatch) -> str:
    """The peak matching of a scorecard in words, e.g. ``peaks: 9/10 objects matched within 2 voxels,
    1 false; precision 0.900, recall 0.900; localisation error ...``."""
    unit = p.unit
    error = (
        ""
        if not p.matched
        else f"; localisation error mean {p.mean_error:.3g} {unit}, RMS {p.rms_error:.3g} {unit}"
    )
    return (
        f"peaks: {p.describe(matched=f' matched within {p.tolerance:g} {p.tolerance_unit}')}; "
        f"precision {p.precision:.3f}, recall {p.recall:.3f}{error}"
    )


def _print_card(card, prefix: str) -> None:
    report = card.report
    print(prefix + card.summary(precise=True))
    for row in card.table():
        print(prefix + row)
    sigma = ", ".join(f"{s:g}" for s in report.ssim_sigma)
    print(f"{prefix}{card.normalization}; SSIM Gaussian window sigma ({sigma}) voxels")
    if card.peaks is not None:
        print(prefix + peaks_line(card.peaks))
    print(f"{prefix}floors: the all-zero volume and the truth's mean everywhere, scored the same way; "
          "margin = value - the best floor")  # fmt: skip


def run_metrics(args: argparse.Namespace) -> int:
    """Handler of ``metrics``: the scorecard with floors (and per-depth curves, LPIPS) as text or JSON."""
    from lfm_studio.engine.image_quality import LPIPSUnavailableError, lpips, scorecard

    require_file("--truth", args.truth, "the ground-truth volume TIFF (e.g. from 'lfm-studio image --truth')")
    require_file("--estimate", args.estimate, "the reconstructed volume TIFF (from 'lfm-studio reconstruct')")
    (truth, truth_known), (estimate, estimate_known) = (
        _read_for_metrics(args.truth),
        _read_for_metrics(args.estimate),
    )
    _check_grids(args, truth, estimate, truth_known and estimate_known)
    use_peaks, options = _peak_settings(args, truth, truth_known)
    frames = estimate.data if estimate.data.ndim == 4 else estimate.data[None]
    cards, reports = [], []
    for frame in frames:
        card = scorecard(
            truth.data, frame, normalize=args.normalize, data_range=args.data_range, peaks=use_peaks,
            peak_options=options, voxel_size=truth.voxel_size if truth_known else None,
            per_depth=args.per_depth, depths=truth.depth_values(),
        )  # fmt: skip
        report = card.to_dict()
        if args.lpips:
            try:
                report["lpips"] = float(lpips(truth.data, frame, data_range=report["data_range"]))
            except LPIPSUnavailableError as error:
                raise ValueError(str(error)) from error
        cards.append(card)
        reports.append(report)
    if args.json:
        output = reports[0] if estimate.data.ndim == 3 else {"frames": reports}
        print(json.dumps(output, indent=2, allow_nan=False))
        return 0
    for t, (card, report) in enumerate(zip(cards, reports, strict=True)):
        prefix = f"frame {t}: " if len(cards) > 1 else ""
        _print_card(card, prefix)
        if "lpips" in report:
            print(f"{prefix}LPIPS {report['lpips']:.4f} (lower is more similar)")
        if "per_depth" in report:
            curves = report["per_depth"]
            print(f"{prefix}{'depth (um)':>12} {'PSNR (dB)':>10} {'SSIM':>7}")
            for z, p, s in zip(curves["depths_um"], curves["psnr_db"], curves["ssim"], strict=True):
                print(f"{prefix}{z:12.3f} {'inf' if p is None else f'{p:.3f}':>10} {s:7.4f}")
    return 0


def add_metrics_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``metrics`` on ``subparsers`` (from ``parser.add_subparsers()``)."""
    met = subparsers.add_parser(
        "metrics",
        help="NCC, bead F1, PSNR and SSIM of a reconstructed volume against a ground truth, beside the "
        "scores of an all-zero and a constant volume",
        description="Scores a reconstruction against its ground truth: NCC (Pearson correlation), for point and "
        "bead phantoms the F1 of local maxima matched to the truth's within a tolerance (with the localisation "
        "error), then PSNR and SSIM (Gaussian window, sigma 1.5; Wang et al. 2004) on the stated normalisation "
        "and data range (default: the truth's max - min). Each score is printed beside the all-zero and "
        "constant volumes' scores and the margin over them. A (T, Z, Y, X) estimate is scored frame by frame.",
    )
    met.add_argument("--truth", required=True, help="ground-truth volume TIFF (Z, Y, X)")
    met.add_argument("--estimate", required=True, help="reconstructed volume TIFF (Z, Y, X) or (T, Z, Y, X)")
    met.add_argument(
        "--data-range", type=float, default=None, help="R of PSNR/SSIM (default: truth max - min)"
    )
    met.add_argument(
        "--normalize",
        choices=NORMALIZATIONS,
        default="none",
        help="before PSNR/SSIM, fit the estimate to the truth: scale (least squares a * estimate), affine "
        "(a * estimate + c), sum (same total); default none (compare in the truth's units)",
    )
    peaks = met.add_argument_group("bead matching (F1)")
    peaks.add_argument(
        "--peaks",
        choices=("auto", "on", "off"),
        default="auto",
        help="match local maxima to the truth's: auto = when the truth is a bead phantom or point-like",
    )
    peaks.add_argument(
        "--peak-threshold",
        type=float,
        default=0.1,
        help="a peak exceeds this fraction of the estimate's maximum (default 0.1)",
    )
    peaks.add_argument(
        "--tolerance-voxels", type=float, default=2.0, help="match distance in voxels (default 2)"
    )
    peaks.add_argument(
        "--tolerance-um", type=float, default=None, help="match distance in um (instead of voxels)"
    )
    met.add_argument("--per-depth", action="store_true", help="also PSNR/SSIM of each z slice")
    met.add_argument(
        "--lpips", action="store_true", help="also LPIPS (needs lpips and its weights installed locally)"
    )
    met.add_argument("--json", action="store_true", help="print JSON (null = infinite or undefined)")
    met.set_defaults(handler=run_metrics)
