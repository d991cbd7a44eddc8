"""``lfm-studio bench``: run time against error for every accuracy knob (the Pareto table and plot).

    lfm-studio bench [--design NAME|FILE ...] [--quick] [--grid-only] [--out DIR] [--json] [--repeats N]

For each design (default: every shipped preset) the PSF stack is computed at the
converged reference and at every knob setting (one knob changed from the standard
preset at a time, plus the presets); the table gives the time (fastest of the
interleaved rounds), its ratio to the standard preset in the same run, the worst-depth
relative PSF error and the reconstruction error, and marks the Pareto front.
The volume-grid rows (``voxels_per_lenslet`` / ``volume_oversampling``) time the PSF and
projector set-up on each grid and give the reconstructed two-point resolution instead of
the PSF error (not comparable across grids); ``--quick`` leaves them out, ``--grid-only``
runs just them and the standard preset. ``--out`` writes ``accuracy_table.md``, ``accuracy.json`` and ``accuracy_pareto.png``.
Register with :func:`add_bench_parser`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

QUICK_ITERATIONS = 5


def add_bench_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Add the ``bench`` sub-command to ``subparsers``; returns it."""
    bench = subparsers.add_parser(
        "bench",
        help="run time against error of every accuracy knob (Pareto table and plot)",
        description=__doc__.split("\n\n")[0],
    )
    bench.add_argument(
        "--design", action="append", default=None, metavar="NAME|FILE",
        help="preset name or design file (repeatable); default: every shipped preset",
    )  # fmt: skip
    bench.add_argument(
        "--quick", action="store_true",
        help="fewer settings, one round, no reference refinement check, 5 RL iterations (a smoke run)",
    )  # fmt: skip
    bench.add_argument(
        "--grid-only", action="store_true",
        help="only the standard preset and the volume-grid rows (time and two-point resolution per grid)",
    )  # fmt: skip
    bench.add_argument("--out", default=None, metavar="DIR", help="write the table, JSON and PNG plot here")
    bench.add_argument("--json", action="store_true", help="print JSON instead of the Markdown table")
    bench.add_argument(
        "--repeats", type=int, default=None, help="interleaved timing rounds (default 2; quick 1)"
    )
    bench.add_argument("--overwrite", action="store_true", help="replace existing files in --out")
    bench.add_argument(
        "--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)"
    )
    bench.set_defaults(handler=run_bench)
    return bench


def _outputs(out: Path, overwrite: bool) -> dict[str, Path]:
    paths = {
        "table": out / "accuracy_table.md",
        "json": out / "accuracy.json",
        "png": out / "accuracy_pareto.png",
    }
    if not overwrite:
        taken = [str(p) for p in paths.values() if p.exists()]
        if taken:
            raise FileExistsError(
                f"{', '.join(taken)} exist(s). Fix: choose another --out or pass --overwrite."
            )
    return paths


def run_bench(args: argparse.Namespace) -> int:
    """Handler of ``bench``: run the sweep, print the table, write the files; 0 on success."""
    from lfm_studio.bench import format_table, resolve_case, run_case, shipped_cases, write_pareto_png
    from lfm_studio.bench.grid import grid_settings
    from lfm_studio.bench.knobs import KnobSetting, preset_options
    from lfm_studio.bench.metrics import ITERATIONS
    from lfm_studio.cli.progress import progress_bar
    from lfm_studio.engine.atomic_write import atomic_write

    if args.repeats is not None and args.repeats < 1:
        raise ValueError(f"--repeats must be >= 1; got {args.repeats}. Fix: use 1 or 2.")
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    paths = None
    if args.out is not None:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        paths = _outputs(out, args.overwrite)
    cases = [resolve_case(d) for d in args.design] if args.design else shipped_cases()
    repeats = args.repeats or (1 if args.quick else 2)
    results = []
    for case in cases:
        only = args.grid_only
        settings = [KnobSetting("preset", "standard", preset_options(case, "standard"))] if only else None
        with progress_bar(f"bench {case.name}") as progress:
            results.append(
                run_case(
                    case, quick=args.quick, repeats=repeats, check_reference=not (args.quick or only),
                    iterations=QUICK_ITERATIONS if args.quick else ITERATIONS, settings=settings,
                    grid=grid_settings(case) if only else None, progress=progress,
                )
            )  # fmt: skip
    table = format_table(results)
    document = json.dumps({"cases": [r.as_dict() for r in results]}, indent=1, allow_nan=False)  # NaN: null
    print(document if args.json else table)
    if paths is not None:
        atomic_write(paths["table"], lambda fh: fh.write(table.encode()), overwrite=args.overwrite)
        atomic_write(paths["json"], lambda fh: fh.write(document.encode()), overwrite=args.overwrite)
        write_pareto_png(results, paths["png"], overwrite=args.overwrite)
        print(f"wrote {paths['table']}, {paths['json']}, {paths['png']}", file=sys.stderr)
    return 0
