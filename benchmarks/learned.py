"""Learned reconstruction against Richardson-Lucy on held-out phantoms (issue: learned reconstruction).

    python benchmarks/learned.py [--quick] [--preset flfm_guo2019] [--pixels 512] [--depths 32]
        [--minutes 10] [--models unrolled-rl multiwiener unet] [--seeds 0 1 2] [--test 50]
        [--photons 1e4 1e5 1e6] [--threads 1] [--mismatch 0.05] [--train-jitter 0]
        [--validate-every 50] [--patience 20] [--config '{"width": 24}'] [--no-rl-best]

Every run prints its thread settings and the load average after each training and test set. For each model and training seed: train on the design's
own forward model (beads, the photon budgets given, ``--minutes`` each), then score on
``--test`` held-out phantoms per photon budget (test split: seeds disjoint from training and
validation) against RL-30 (plain Richardson-Lucy, 30 iterations), RL at its best iteration
(chosen on the validation split, up to 100), accelerated RL (30 iterations), the
back-projection ``A^T y / A^T 1`` and the all-zero volume. Scores: NCC, bead F1, localisation
error (um), PSNR and SSIM after least-squares scale matching; time per frame (median); training
time; the one-step Tikhonov (per frequency on a Fourier LFM, per lenslet-lattice frequency on a
conventional one) is a baseline too. Two harder test sets follow: an unseen phantom class (cells, trained on beads) and an
optics mismatch of ``--mismatch`` (default 5 %): images through 4 jittered designs whose MLA and
Fourier lens focal lengths, NA and wavelength are each scaled by a factor in [0.95, 1.05]
(:func:`lfm_studio.engine.learned.mismatch.jittered_designs`, the same code as training's
``optics_jitter``), reconstructed with the nominal projector. ``--train-jitter`` trains the
models with that optics-mismatch augmentation (``TrainingDataSpec.optics_jitter``). Mean and
spread (min..max) over the training seeds.

Training validates on 8 samples every ``--validate-every`` steps (default 50; it was 10, which
cost about a quarter of a fast model's steps) and stops early after ``--patience`` validations
without improvement; ``--config`` passes a model config (JSON) to the one model trained;
``--no-rl-best`` skips the slowest baseline.

``--quick``: a 256 px camera, 5 depths, 1 seed, 1 minute per model, 6 test phantoms.
Goal (on this 2-core CPU, 512^2 x 32 depths): a model trained in <= 10 min with <= 200k
parameters that matches or beats RL-30 on NCC and bead F1 at >= 10x less time per frame.
"""

from __future__ import annotations

import lfm_studio  # noqa: F401  # isort: skip  (first: sets OMP_WAIT_POLICY before torch loads, engine/threads.py)
import argparse
import json
import math
import os
import statistics
import time
import warnings
from collections.abc import Callable

import torch

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.image_quality.scorecard import scorecard
from lfm_studio.engine.learned.data import Sample, TrainingDataSpec, make_samples
from lfm_studio.engine.learned.mismatch import mismatch_pool
from lfm_studio.engine.learned.models import parameter_count
from lfm_studio.engine.learned.models.common import adjoint_normaliser
from lfm_studio.engine.learned.train import train
from lfm_studio.engine.reconstruct.dispatch import reconstruct_frame
from lfm_studio.engine.reconstruct.richardson_lucy import richardson_lucy_iterates
from lfm_studio.engine.simulation import imaging_setup, simulate_psf
from lfm_studio.engine.threads import describe_threads, torch_threads

Method = Callable[[torch.Tensor], torch.Tensor]


def small_design(preset: str, pixels: int, depths: int):
    design = load_preset(preset)
    camera = type(design.camera)(**{**design.camera.model_dump(), "pixel_count": (pixels, pixels)})
    low, high = design.depths.depth_range_um
    step = (high - low) / max(depths - 1, 1)
    spec = type(design.depths)(depth_range_um=(low, low + step * (depths - 1)), depth_step_um=step)
    return design.updated(camera=camera, depths=spec)


def scores(samples: list[Sample], method: Method, voxel: tuple[float, float, float]) -> dict[str, float]:
    """Mean NCC, F1, localisation error (um), PSNR, SSIM and the median seconds per frame."""
    rows, seconds = [], []
    for sample in samples:
        began = time.perf_counter()
        with torch.no_grad():
            estimate = method(sample.image)
        seconds.append(time.perf_counter() - began)
        card = scorecard(sample.truth, estimate, normalize="scale", peaks=True, voxel_size=voxel)
        row = {score.key: score.value for score in card.scores}
        row["loc_um"] = card.peaks.mean_error if card.peaks is not None else math.nan
        rows.append(row)
    out = {key: statistics.fmean(r[key] for r in rows if not math.isnan(r[key])) if any(not math.isnan(r[key]) for r in rows) else math.nan
           for key in rows[0]}  # fmt: skip
    out["s_per_frame"] = statistics.median(seconds)
    return out


def best_rl_iteration(setup, samples: list[Sample], limit: int = 100) -> int:
    """The plain-RL iteration with the best mean NCC on ``samples`` (validation)."""
    from lfm_studio.engine.image_quality import ncc

    totals = [0.0] * limit
    for sample in samples:
        for k, iterate in enumerate(
            richardson_lucy_iterates(setup.projector, sample.image.clamp_min(0), iterations=limit)
        ):
            totals[k] += float(ncc(sample.truth, iterate.estimate))
    return 1 + max(range(limit), key=totals.__getitem__)


def rl(setup, iterations: int, method: str = "rl") -> Method:
    return lambda y: reconstruct_frame(setup.projector, y.clamp_min(0), method=method, iterations=iterations)


def print_table(title: str, rows: dict[str, list[dict[str, float]]]) -> None:
    """One row per method: the value, or over several training seeds ``mean (min..max)`` (never cut)."""
    keys = ("ncc", "f1", "loc_um", "psnr_db", "ssim", "s_per_frame")
    width = 18 if all(len(runs) == 1 for runs in rows.values()) else 30
    print(f"\n{title}")
    print(f"{'method':<22}" + "".join(f"{k:>{width}}" for k in keys))
    for name, runs in rows.items():
        cells = []
        for key in keys:
            values = [r[key] for r in runs if not math.isnan(r[key])]
            if not values:
                cells.append(f"{'-':>{width}}")
            elif len(values) == 1:
                cells.append(f"{values[0]:>{width}.4g}")
            else:
                cells.append(
                    f"{statistics.fmean(values):.4g} ({min(values):.3g}..{max(values):.3g})".rjust(width)
                )
        print(f"{name:<22}" + "".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--preset", default="flfm_guo2019")
    parser.add_argument("--pixels", type=int, default=512)
    parser.add_argument("--depths", type=int, default=32)
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--models", nargs="+", default=["unrolled-rl", "multiwiener", "unet"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--test", type=int, default=50)
    parser.add_argument("--photons", nargs="+", type=float, default=[1e4, 1e5, 1e6])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--validate-every", type=int, default=50, help="training steps between validations (8 samples each)"
    )
    parser.add_argument(
        "--patience", type=int, default=20, help="validations without improvement before stopping"
    )
    parser.add_argument(
        "--rl-best",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also score RL at its best iteration on the validation split (up to 100; the slowest baseline)",
    )
    parser.add_argument(
        "--config", default="{}", help="model config as JSON, e.g. '{\"width\": 24}' (one model)"
    )
    parser.add_argument(
        "--mismatch", type=float, default=0.05, help="relative optics jitter of the mismatch test set"
    )
    parser.add_argument(
        "--train-jitter", type=float, default=0.0, help="optics_jitter of the training data (0: off)"
    )
    args = parser.parse_args()
    if args.quick:
        args.pixels, args.depths, args.minutes, args.seeds, args.test = 256, 5, 1.0, [0], 6
    warnings.simplefilter("ignore", DesignWarning)
    with torch_threads(args.threads):
        print(describe_threads())
        design = small_design(args.preset, args.pixels, args.depths)
        setup = imaging_setup(simulate_psf(design))
        mismatched = mismatch_pool(design, args.mismatch, count=4, seed=99)
        voxel = setup.voxel_size
        print(
            f"{args.preset}: camera {args.pixels}^2, volume {setup.volume_shape}, voxel {[f'{v * 1e6:.3g}' for v in voxel]} um"
        )
        train_data = TrainingDataSpec(phantoms="beads", photons=tuple(args.photons))
        per_budget = max(1, args.test // len(args.photons))
        tests = {
            "beads (seen class)": [s for p in args.photons for s in make_samples(TrainingDataSpec(phantoms="beads", photons=(p,), seed=99), setup, "test", per_budget)],
            "cells (unseen class)": make_samples(TrainingDataSpec(phantoms="cells", photons=tuple(args.photons), seed=99), setup, "test", per_budget),
            f"beads, {args.mismatch:.0%} optics mismatch": make_samples(TrainingDataSpec(phantoms="beads", photons=tuple(args.photons), seed=99), setup, "test", per_budget, imaging=mismatched),
        }  # fmt: skip
        norm = adjoint_normaliser(setup.projector)
        baselines: dict[str, Method] = {
            "all-zero": lambda y: torch.zeros(setup.volume_shape),
            "back-projection": lambda y: setup.projector.adjoint(y) / norm,
            "Tikhonov (snr 1000)": lambda y: reconstruct_frame(setup.projector, y, method="tikhonov"),
            "RL-30": rl(setup, 30),
        }
        if args.rl_best:
            best = best_rl_iteration(setup, make_samples(train_data, setup, "validation", 4))
            baselines[f"RL-best ({best} it.)"] = rl(setup, best)
        baselines["RL-accelerated-30"] = rl(setup, 30, "rl-accelerated")
        models: dict[str, list] = {}
        config = json.loads(args.config)
        if config and len(args.models) != 1:
            parser.error("--config applies to one model; give one --models name with it")
        print(f"training: {args.minutes} min per model, validation every {args.validate_every} steps, "
              f"patience {args.patience} validations, config {config or 'default'}")  # fmt: skip
        for name in args.models:
            for seed in args.seeds:
                began = time.perf_counter()
                data = TrainingDataSpec(
                    phantoms="beads", photons=tuple(args.photons), seed=seed, optics_jitter=args.train_jitter
                )
                result = train(setup, model=name, config=config, data=data, budget_minutes=args.minutes, seed=seed,
                               threads=args.threads, design=design, validate_every=args.validate_every,
                               patience=args.patience)  # fmt: skip
                print(f"trained {name} seed {seed}: {parameter_count(result.model)} parameters, "
                      f"{result.header.training['steps']} steps, {time.perf_counter() - began:.0f} s ({result.stop_reason})")  # fmt: skip
                models.setdefault(name, []).append(result.model)
                print(f"load average (1, 5, 15 min): {os.getloadavg()}")
        for title, samples in tests.items():
            rows = {label: [scores(samples, method, voxel)] for label, method in baselines.items()}
            for name, trained in models.items():
                rows[name] = [scores(samples, model, voxel) for model in trained]
            print_table(f"{title}: {len(samples)} phantoms, photons {args.photons}", rows)
            print(f"load average (1, 5, 15 min): {os.getloadavg()}")


if __name__ == "__main__":
    main()
