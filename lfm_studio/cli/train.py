"""``lfm-studio train``: train a learned reconstructor from a design's own forward model.

The PSF stack is simulated from the design (or read with ``--psf``), training pairs are
generated on the fly (:mod:`lfm_studio.engine.learned.data`), and the best model on the
validation set is written as a safetensors checkpoint (``--out``) that ``lfm-studio
reconstruct --method learned --model`` applies to images of the same design.
"""

from __future__ import annotations

import argparse
import json

from lfm_studio.cli.input_files import require_file
from lfm_studio.cli.interrupts import watching
from lfm_studio.cli.progress import progress_bar


def _photon_list(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError as error:
        raise argparse.ArgumentTypeError(
            f"--photons must be numbers separated by commas; got {text!r}"
        ) from error
    return values


def _optics_jitter(text: str) -> float:
    from lfm_studio.engine.learned.mismatch import JITTER_LIMIT

    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 <= value <= JITTER_LIMIT:  # NaN fails too
        raise argparse.ArgumentTypeError(
            f"--optics-jitter must be a relative jitter between 0 and {JITTER_LIMIT:g}; got {text!r}. "
            f"Fix: give a fraction, e.g. --optics-jitter 0.03 for +-3 % (not a percentage)."
        )
    return value


def _model_config(text: str) -> dict[str, object]:
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        value = error
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(
            f"--config must be a JSON object of model options; got {text!r}. "
            "Fix: e.g. --config '{\"learn_filters\": true}' for multiwiener (see docs/learned.md)."
        )
    return value


@watching("out", complete="it holds the best model so far. Fix: continue training with --resume.")
def run_train(args: argparse.Namespace) -> int:
    from lfm_studio.cli.simulate import _design_file
    from lfm_studio.engine.design import resolve_design
    from lfm_studio.engine.io import check_output, read_psf_stack
    from lfm_studio.engine.learned.data import TrainingDataSpec
    from lfm_studio.engine.learned.design_setup import stack_identity
    from lfm_studio.engine.learned.train import train
    from lfm_studio.engine.simulation import imaging_setup, simulate_psf

    require_file("--psf", args.psf, "a PSF stack TIFF from 'lfm-studio simulate', or leave --psf out")
    out = check_output(
        args.out, overwrite=args.overwrite or args.resume, inputs=[_design_file(args.design), args.psf]
    )
    design = resolve_design(args.design)
    data = TrainingDataSpec(
        phantoms=args.phantoms, photons=args.photons, seed=args.seed, optics_jitter=args.optics_jitter
    )
    if args.psf is not None:
        stack = read_psf_stack(args.psf)
    else:
        with progress_bar(f"PSF stack ({design.kind}, {len(design.depths.values)} depths)") as progress:
            stack = simulate_psf(design, progress=progress)
    design_hash, depths = stack_identity(stack)
    setup = imaging_setup(stack)
    threads = args.torch_threads if args.torch_threads is not None else 1
    unit = "step" if args.steps is not None else "s"  # the engine counts capped steps, else budget seconds
    with progress_bar(
        f"training {args.model} ({args.minutes:g} min budget, {threads} thread)", unit
    ) as progress:
        result = train(
            setup, model=args.model, config=args.config, data=data, budget_minutes=args.minutes, max_steps=args.steps, seed=args.seed,
            design_hash=design_hash, depths=depths, design=stack.design, checkpoint=out, resume=args.resume, overwrite=args.overwrite,
            threads=threads, progress=progress,
        )  # fmt: skip
    training = result.header.training
    session = len(result.history)  # one history entry per step of this run; 'seconds' is this run's too
    steps = f"{session} steps in {training['seconds']:.0f} s"
    if session != training["steps"]:  # resumed: the checkpoint counts the earlier runs' steps as well
        steps += f" ({training['steps']} in all)"
    print(
        f"wrote {out}: {args.model}, {training['parameters']} parameters, {steps} "
        f"(stopped: {result.stop_reason}); validation loss "
        f"{training['best_validation']:.4f} (all-zero volume: {training['zero_floor']:.1f}), "
        f"validation NCC {result.header.metrics['validation_ncc']:.3f}"
    )
    return 0


def add_train_parser(sub: argparse._SubParsersAction) -> None:
    from lfm_studio.engine.learned.models import DEFAULT_MODEL, MODELS

    train = sub.add_parser(
        "train",
        help="train a learned reconstructor (unrolled RL, MultiWienerNet, U-Net) from a design",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    train.add_argument("design", help="design file (.json) or preset name")
    train.add_argument("--out", required=True, help="checkpoint to write (.safetensors)")
    train.add_argument("--model", choices=sorted(MODELS), default=DEFAULT_MODEL)
    train.add_argument(
        "--config", type=_model_config, default=None, metavar="JSON",
        help="the model's options as a JSON object, e.g. '{\"iterations\": 8}' for unrolled-rl or "
        "'{\"learn_filters\": true}' for multiwiener (default: the model's defaults)",
    )  # fmt: skip
    train.add_argument("--minutes", type=float, default=10.0, help="wall-clock training budget (default 10)")
    train.add_argument(
        "--steps", type=int, default=None, help="stop after this many steps (reproducible runs)"
    )
    train.add_argument(
        "--psf", default=None, help="PSF stack TIFF to train on instead of simulating the design's"
    )
    train.add_argument("--phantoms", choices=("beads", "cells", "mix"), default="mix")
    train.add_argument(
        "--photons", type=_photon_list, default=(1e4, 1e5, 1e6),
        help="photon budgets per image, comma-separated (default 1e4,1e5,1e6)",
    )  # fmt: skip
    train.add_argument(
        "--optics-jitter", type=_optics_jitter, default=0.0, metavar="FRACTION",
        help="optics-mismatch augmentation: image the training phantoms through designs with the MLA and "
        "Fourier lens focal lengths, NA and wavelength jittered by up to this fraction (e.g. 0.03 = 3 %%; "
        "0 = off, at most 0.2); the model keeps the nominal design. Needs the design, not a bare --psf",
    )  # fmt: skip
    train.add_argument("--seed", type=int, default=0, help="seed of the training data and weights")
    train.add_argument("--resume", action="store_true", help="continue training the model in --out")
    train.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    train.set_defaults(handler=run_train)
