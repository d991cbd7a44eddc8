"""``lfm-studio resolution DESIGN``: the reconstructed two-point resolution of a design.

Two equal point emitters are imaged through the design at growing separations and
reconstructed with plain Richardson-Lucy; the smallest separation whose reconstruction
dips below 0.735 (Rayleigh-like) is reported, lateral and axial, per depth, as a table
or ``--json`` (:func:`~lfm_studio.engine.performance.reconstructed.reconstructed_resolution`).
The volume grid comes from the design (``accuracy.voxels_per_lenslet``,
``accuracy.volume_oversampling``) unless ``--voxels-per-lenslet`` /
``--volume-oversampling`` override it; no value can be below the grid floor of 2 voxels.
``--crop`` (default 256 camera pixels about the axis, 0 = the whole sensor) keeps it
to seconds or minutes on a CPU; views outside the crop are lost. Register with
:func:`add_resolution_parser`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from lfm_studio.cli.simulate import allow_negative_values, resolve_device
from lfm_studio.engine.design import resolve_design
from lfm_studio.engine.performance.reconstructed import ResolutionReport, reconstructed_resolution
from lfm_studio.engine.performance.table import align


def _depth_list(text: str) -> tuple[float, ...]:
    """``"0,20,-10"`` (um) -> metres."""
    try:
        values = tuple(float(part) * 1e-6 for part in text.split(",") if part.strip())
    except ValueError:
        values = ()
    if not values:
        raise argparse.ArgumentTypeError(
            f"--depths must be comma-separated depths in um, e.g. 0,20; got {text!r}."
        )
    return values


def add_resolution_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``resolution`` sub-command to ``subparsers``; returns it."""
    p = allow_negative_values(
        subparsers.add_parser(
            "resolution",
            help="reconstructed two-point resolution (plain RL), lateral and axial, per depth",
            description=(
                "Image two equal point emitters through the design at growing separations, reconstruct "
                "with plain Richardson-Lucy and report the smallest separation with a dip below the "
                "Rayleigh-like 0.735, lateral and axial, per depth."
            ),
        )
    )
    p.add_argument("design", help="preset name (e.g. xlfm_cong2017) or path to a .json design file")
    p.add_argument(
        "--depths", type=_depth_list, default=(0.0,), help="depths in um, comma separated (default 0)"
    )
    p.add_argument(
        "--photons", type=float, default=None, help="detected photons per emitter (default: noise free)"
    )
    p.add_argument("--iterations", type=int, default=100, help="plain RL iterations (default 100)")
    p.add_argument(
        "--crop", type=int, default=256, help="camera pixels kept about the axis (default 256; 0 = all)"
    )
    p.add_argument("--depth-step", type=float, default=None, help="axial voxel in um (default: the design's)")
    p.add_argument("--max-lateral", type=float, default=10.0, help="largest lateral separation tried, um")
    p.add_argument("--max-axial", type=float, default=30.0, help="largest axial separation tried, um")
    p.add_argument("--voxels-per-lenslet", type=int, default=None, help="conventional LFM volume grid (odd)")
    p.add_argument("--volume-oversampling", type=int, default=None, help="Fourier LFM voxels per pixel (odd)")
    p.add_argument("--seed", type=int, default=0, help="shot-noise seed")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="torch device (default cpu)")
    p.add_argument("--json", action="store_true", help="print JSON (lengths in um) instead of a table")
    p.set_defaults(handler=run_resolution)
    return p


def format_resolution_table(report: ResolutionReport) -> str:
    """The report as aligned text; a footnote explains "n/a" when a separation is n/a."""

    def um(value: float | None) -> str:
        return "n/a" if value is None else f"{value / 1e-6:.4g}"

    noise = "noise free" if report.photons is None else f"{report.photons:g} photons per emitter"
    crop = "whole sensor" if report.crop is None else f"sensor crop {report.crop} px"
    rows = [["depth_um", "lateral_um", "axial_um"]]
    rows += [[um(d.depth), um(d.lateral), um(d.axial)] for d in report.depths]
    return "\n".join(
        [
            f"{report.design_name}  (kind {report.kind}): two-point resolution after plain RL",
            f"  {report.iterations} iterations, {noise}, dip < {report.threshold:g}, {crop}",
            f"  lateral voxel {um(report.lateral_voxel)} um (grid floor {um(report.lateral_grid_floor)} um), "
            f"axial step {um(report.axial_voxel)} um (grid floor {um(report.axial_grid_floor)} um)",
            "",
            *align(rows),
            *(["", "  n/a: not resolved up to --max-lateral / --max-axial."] if _unresolved(report) else []),
        ]
    )


def _unresolved(report: ResolutionReport) -> bool:
    """True when some depth's lateral or axial separation is n/a (none resolved up to the largest tried)."""
    return any(d.lateral is None or d.axial is None for d in report.depths)


def run_resolution(args: argparse.Namespace) -> int:
    """Handler of ``resolution``: print the report (refusals raise; ``cli.main`` prints them and
    picks the exit code)."""
    design = resolve_design(args.design)
    overrides = {
        key: value
        for key, value in (
            ("voxels_per_lenslet", args.voxels_per_lenslet),
            ("volume_oversampling", args.volume_oversampling),
        )
        if value is not None
    }
    if overrides:
        design = design.updated(accuracy={**design.accuracy.model_dump(), **overrides})
    start = time.perf_counter()
    report = reconstructed_resolution(
        design,
        args.depths,
        depth_step=None if args.depth_step is None else args.depth_step * 1e-6,
        photons=args.photons,
        iterations=args.iterations,
        crop=args.crop or None,
        max_lateral=args.max_lateral * 1e-6,
        max_axial=args.max_axial * 1e-6,
        seed=args.seed,
        device=resolve_device(args.device),
    )
    print(f"lfm-studio resolution: {time.perf_counter() - start:.1f} s", file=sys.stderr)
    print(json.dumps(report.to_dict(), indent=2) if args.json else format_resolution_table(report))
    return 0
