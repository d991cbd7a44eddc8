"""Optimiser cost: seconds per evaluated candidate against the lenslet count, and the overhead share.

    python benchmarks/optimize.py [--quick] [--counts 3 9 15 27] [--crop 512] [--depths 5]
        [--iterations 20] [--trials 4] [--threads 1]

Every run prints its thread settings (torch threads, cores, OMP_WAIT_POLICY).

For each lenslet count N: the XLFM preset (xlfm_cong2017) keeps its N innermost lenslets; a
stored study (SQLite in a temporary folder, grid sampler) evaluates ``--trials`` candidates
that each change the focal length of lenslet 0 (the first one computes all N lenslets, the
next ones reuse N - 1 from the per-lenslet cache) on the task score ``task_ncc`` (a seeded
bead phantom imaged at 1e5 photons on a ``--crop`` px sensor crop, ``--depths`` depths over
+-40 um, plain RL ``--iterations`` iterations, one held-out seed).

Per trial the table gives the stages the evaluator times (PSF = PSF stack + projector OTFs;
image = phantom and camera image; RL = reconstruction; score) and the wall time between two
stored trials; overhead = wall - stages (design build and checks, Optuna's sampler and its
SQLite commits, the record's design JSON). Goal: PSF + reconstruction are most of the wall time.

``--demo``: starting from the shipped XLFM (xlfm_cong2017), a grid search over the second
lenslet group's focal length (the multifocal spread; hand design 28.5 mm) maximises
``task_ncc`` (RL reconstructions of held-out bead phantoms, seeds 1000 and 1001, 1e5
photons), with the closed-form field of view and depth of field required to stay at least
the hand design's. The best design is then checked on an *unoptimised* metric: bead F1 and
localisation error on other phantoms (seeds 2000-2003), against the hand design at the same
photon budget.
"""

from __future__ import annotations

import lfm_studio  # noqa: F401  # isort: skip  (first: sets OMP_WAIT_POLICY before torch loads)
import argparse
import statistics
import tempfile
import time
import warnings
from pathlib import Path

import torch
from optimize_demo import NoWorseFieldAndDepth  # benchmarks/ is the script's folder

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optimize import (
    DEFAULT_CONSTRAINTS,
    Candidate,
    DesignSpace,
    EvaluationSettings,
    Evaluator,
    Parameter,
    TaskScore,
    grid_search,
)
from lfm_studio.engine.optimize.study import run_study
from lfm_studio.engine.performance import closed_form_metrics
from lfm_studio.engine.threads import describe_threads

STAGES = ("psf_s", "simulate_s", "reconstruct_s", "score_s")


def design_with(count: int, depths: int):
    """XLFM with its ``count`` lenslets nearest the axis and ``depths`` depths over +-40 um."""
    design = load_preset("xlfm_cong2017")
    lenslets = sorted(design.mla.lenslets, key=lambda lens: lens.center_um[0] ** 2 + lens.center_um[1] ** 2)
    step = 80.0 / max(depths - 1, 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        return design.updated(
            mla={"layout": "lenslets", "lenslets": [lens.model_dump() for lens in lenslets[:count]]},
            depths={"depth_range_um": (-40.0, -40.0 + step * (depths - 1)), "depth_step_um": step},
        )


def run(count: int, args: argparse.Namespace, folder: Path) -> list[dict]:
    design = design_with(count, args.depths)
    f0 = design.mla.lenslets[0].focal_length_mm
    space = DesignSpace(
        (
            Parameter(
                "mla.lenslets[0].focal_length_mm", choices=tuple(f0 + 0.1 * i for i in range(args.trials))
            ),
        )
    )
    score = TaskScore("ncc", iterations=args.iterations, photons=1e5, seeds=(1000,))
    evaluator = Evaluator(design, space, [score], settings=EvaluationSettings(crop=args.crop))
    rows: list[dict] = []
    last = [0.0]

    def timed(study, trial, record):
        now = time.perf_counter()
        rows.append({"wall_s": now - last[0], **record.timing, **record.cache})
        last[0] = now

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        last[0] = time.perf_counter()
        run_study(evaluator, f"sqlite:///{folder / f'n{count}.db'}", callbacks=[timed])
    return rows


def demo(args: argparse.Namespace) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        base = load_preset("xlfm_cong2017")
        step = 80.0 / max(args.depths - 1, 1)
        base = base.updated(depths={"depth_range_um": (-40.0, 40.0), "depth_step_um": step})
    hand = closed_form_metrics(base)
    second = ",".join(str(i) for i, lens in enumerate(base.mla.lenslets) if lens.focal_length_mm != 26.0)
    path = f"mla.lenslets[{second}].focal_length_mm"  # the whole second group moves together
    space = DesignSpace((Parameter(path, choices=tuple(args.focal_choices)),))
    keep = NoWorseFieldAndDepth(hand.field_of_view * 1e6, hand.depth_of_field * 1e6)
    settings = EvaluationSettings(crop=args.crop)
    optimised = TaskScore("ncc", iterations=args.iterations, photons=1e5, seeds=(1000, 1001))
    evaluator = Evaluator(
        base, space, [optimised], constraints=(*DEFAULT_CONSTRAINTS, keep), settings=settings
    )
    print(
        f"XLFM demo: second-group focal length in {args.focal_choices} mm (hand 28.5), {args.crop} px crop, "
        f"{args.depths} depths over +-40 um, RL {args.iterations} it, 1e5 photons, torch threads {torch.get_num_threads()}"
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        result = grid_search(evaluator)
    for r in result.records:
        value = (
            "infeasible: " + str(r.infeasible) if r.values is None else f"task_ncc {r.values['task_ncc']:.4f}"
        )
        print(f"  f2 {r.params[path]:5.2f} mm: {value}")
    if result.best is None:
        print("no feasible candidate")
        return
    hand_record = next(r for r in result.records if r.params[path] == 28.5)
    print(
        f"optimised: f2 {result.best.params[path]} mm, task_ncc {result.best.values['task_ncc']:.4f} "
        f"(hand 28.5 mm: {hand_record.values['task_ncc']:.4f})"
    )
    held_out = tuple(range(2000, 2000 + args.check_seeds))
    for label, record in (("hand", hand_record), ("optimised", result.best)):
        design = space.apply(base, record.params)
        candidate = Candidate(design, settings)
        f1 = TaskScore("f1", iterations=args.iterations, photons=1e5, seeds=held_out)(candidate)
        loc = TaskScore("localisation", iterations=args.iterations, photons=1e5, seeds=held_out)(candidate)
        m = closed_form_metrics(design)
        print(
            f"  {label:9s} f2 {record.params[path]:5.2f} mm: bead F1 {f1:.3f}, localisation {loc:.2f} um "
            f"(unoptimised metric, seeds {held_out[0]}-{held_out[-1]}); FoV {m.field_of_view * 1e6:.0f} um, "
            f"DoF {m.depth_of_field * 1e6:.1f} um"
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="counts 3 and 9, 256 px, 3 depths, 3 trials")
    parser.add_argument("--counts", type=int, nargs="+", default=[3, 9, 15, 27])
    parser.add_argument("--crop", type=int, default=512)
    parser.add_argument("--depths", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--trials", type=int, default=4)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--demo", action="store_true", help="optimise the XLFM and check an unoptimised metric"
    )
    parser.add_argument(
        "--focal-choices", type=float, nargs="+", default=[27.0, 27.5, 28.0, 28.5, 29.0, 29.5, 30.0]
    )
    parser.add_argument("--check-seeds", type=int, default=4, help="held-out seeds of the unoptimised check")
    args = parser.parse_args()
    if args.demo:
        torch.set_num_threads(args.threads)
        print(describe_threads())
        demo(args)
        return
    if args.quick:
        args.counts, args.crop, args.depths, args.trials = [3, 9], 256, 3, 3
    torch.set_num_threads(args.threads)
    print(describe_threads())
    print(
        f"XLFM subsets, {args.crop} px crop, {args.depths} depths, plain RL {args.iterations} it, "
        f"{args.trials} trials per count, SQLite study, torch threads {torch.get_num_threads()}"
    )
    head = f"{'N':>3} {'trial':>5} {'miss':>4} {'hit':>4} {'PSF s':>7} {'image s':>7} {'RL s':>7} {'score s':>7} {'wall s':>7} {'overhead':>8}"
    print(head)
    summary = []
    with tempfile.TemporaryDirectory() as tmp:
        for count in args.counts:
            rows = run(count, args, Path(tmp))
            for i, r in enumerate(rows):
                work = sum(r.get(s, 0.0) for s in STAGES)
                print(
                    f"{count:>3} {i:>5} {r['misses']:>4} {r['hits']:>4} {r.get('psf_s', 0):7.3f} "
                    f"{r.get('simulate_s', 0):7.3f} {r.get('reconstruct_s', 0):7.3f} {r.get('score_s', 0):7.3f} "
                    f"{r['wall_s']:7.3f} {max(0.0, 1 - work / r['wall_s']):8.1%}"
                )
            warm = rows[1:] or rows
            summary.append(
                (
                    count,
                    rows[0]["psf_s"],
                    statistics.median(r["psf_s"] for r in warm),
                    statistics.median(r["reconstruct_s"] for r in warm),
                    statistics.median(r["wall_s"] for r in warm),
                    statistics.median(
                        (r.get("psf_s", 0) + r.get("reconstruct_s", 0)) / r["wall_s"] for r in warm
                    ),
                )
            )
    print("\nsummary (medians over the warm-cache trials, one lenslet recomputed each)")
    print(f"{'N':>3} {'cold PSF s':>10} {'warm PSF s':>10} {'RL s':>7} {'wall s':>7} {'PSF+RL share':>12}")
    for count, cold, warm_psf, rl, wall, share in summary:
        print(f"{count:>3} {cold:10.3f} {warm_psf:10.3f} {rl:7.3f} {wall:7.3f} {share:12.1%}")


if __name__ == "__main__":
    main()
