"""The studio's "Train" dock without Qt: settings, the training and comparison jobs, the score table.

Jobs are plain functions ``(ctx, ...) -> result`` for :class:`lfm_studio.widgets.jobs.JobRunner`
(as in :mod:`lfm_studio.ui.pipeline`):

- :func:`train_model` trains a learned reconstructor (:func:`lfm_studio.engine.learned.train`)
  on the studio's current PSF stack, built into a projector exactly as the image stage builds it;
  each step is handed to the GUI with ``ctx.partial((step, loss, validation or NaN))``;
- :func:`compare_with_rl` reconstructs the studio's current light-field image twice, with the
  registry's default method (accelerated Richardson-Lucy, the studio's iterations) and with the
  trained checkpoint (method "learned"), each scored against the image's phantom
  (:func:`lfm_studio.ui.pipeline.reconstruct`: NCC, bead F1, PSNR, SSIM beside the all-zero floor).

Torch threads: :func:`~lfm_studio.engine.learned.train` sets ``threads`` (default 1) around its
work and restores the caller's count; run on a worker thread, that is the worker's count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from lfm_studio.engine.learned.mismatch import check_jitter
from lfm_studio.engine.learned.models import DEFAULT_MODEL, MODELS
from lfm_studio.ui.pipeline import Context, reconstruct
from lfm_studio.ui.results import ImageResult, ReconstructionResult, WorkflowSettings

PHANTOM_KINDS = ("mix", "beads", "cells")


@dataclass(frozen=True)
class TrainSettings:
    """What the Train dock asks for.

    Attributes
    ----------
    model : a name of :data:`lfm_studio.engine.learned.MODELS` ("unrolled-rl", "multiwiener", "unet").
    minutes : wall-clock training budget in minutes (> 0).
    max_steps : stop after this many steps (None: only the budget and early stopping stop it).
    photons : expected photons per training image, one drawn per sample (each > 0).
    phantoms : "mix", "beads" or "cells".
    seed : seed of the training data and the initial weights.
    optics_jitter : optics-mismatch augmentation as a fraction (0.03 = +-3 %; 0 = off, at most
        0.2): the training images are formed through a pool of jittered designs
        (:attr:`lfm_studio.engine.learned.TrainingDataSpec.optics_jitter`, one PSF simulation
        each before training starts); needs the design.
    threads : torch threads for the training (1: small convolutions run fastest on one).
    """

    model: str = DEFAULT_MODEL
    minutes: float = 10.0
    max_steps: int | None = None
    photons: tuple[float, ...] = (1e4, 1e5, 1e6)
    phantoms: str = "mix"
    seed: int = 0
    optics_jitter: float = 0.0
    threads: int = 1

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"model must be one of {sorted(MODELS)}; got {self.model!r}.")
        if not (isinstance(self.minutes, (int, float)) and math.isfinite(self.minutes) and self.minutes > 0):
            raise ValueError(
                f"minutes must be a positive number of minutes; got {self.minutes!r}. Fix: e.g. 10."
            )
        if self.max_steps is not None and not (isinstance(self.max_steps, int) and self.max_steps >= 1):
            raise ValueError(f"max steps must be an integer >= 1 or empty; got {self.max_steps!r}.")
        if not self.photons or any(not (p > 0 and math.isfinite(p)) for p in self.photons):
            raise ValueError(
                f"photon budgets must be positive numbers; got {self.photons!r}. Fix: e.g. 1e4, 1e5, 1e6."
            )
        if self.phantoms not in PHANTOM_KINDS:
            raise ValueError(f"phantoms must be one of {PHANTOM_KINDS}; got {self.phantoms!r}.")
        check_jitter(self.optics_jitter, "optics jitter")


def jitter_refusal(settings: TrainSettings, design: Any) -> str | None:
    """Why ``settings`` cannot train on a PSF stack of ``design`` (None: it can).

    The studio's wording of the engine's rule (:func:`~lfm_studio.engine.learned.mismatch.require_design_for_jitter`):
    optics jitter simulates its jittered PSFs from the design, so a PSF stack without a
    :class:`~lfm_studio.engine.design.Design` (e.g. a measured one) is refused.
    """
    from lfm_studio.engine.design import Design

    if settings.optics_jitter <= 0 or isinstance(design, Design):
        return None
    return (
        f"Optics jitter {100 * settings.optics_jitter:g} % needs the design: the jittered PSFs are simulated "
        "from it, and this PSF stack has none. Fix: set Optics jitter to off, or load the design."
    )


def parse_photons(text: str) -> tuple[float, ...]:
    """Photon budgets from ``"1e4, 1e5, 1e6"`` (commas or spaces); a ValueError naming the field."""
    parts = [p for p in text.replace(",", " ").split() if p]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        raise ValueError(
            f"photon budgets must be numbers separated by commas; got {text!r}. Fix: e.g. 1e4, 1e5."
        ) from None
    if not values or any(not (v > 0 and math.isfinite(v)) for v in values):
        raise ValueError(f"photon budgets must be positive numbers; got {text!r}. Fix: e.g. 1e4, 1e5, 1e6.")
    return values


@dataclass(frozen=True)
class TrainedModel:
    """A finished training: the engine's result, the design it was trained for and its history.

    ``result`` is a :class:`~lfm_studio.engine.learned.TrainingResult` (model, checkpoint header,
    ``history`` of ``(step, loss, validation or NaN)``, stop reason); ``design`` the studio design.
    """

    result: Any
    design: Any
    settings: TrainSettings

    @property
    def summary(self) -> str:
        """One line: model (and optics jitter), parameters, steps, time, stop reason, validation loss against the zero floor."""
        training = self.result.header.training
        ncc = self.result.header.metrics.get("validation_ncc", math.nan)
        jitter = self.settings.optics_jitter
        model = (
            f"{self.settings.model} (optics jitter ±{100 * jitter:g} %)"
            if jitter > 0
            else self.settings.model
        )
        return (
            f"{model}: {training['parameters']} parameters, {training['steps']} steps in "
            f"{training['seconds']:.1f} s (stopped: {self.result.stop_reason}); validation loss "
            f"{training['best_validation']:.4f} (all-zero volume {training['zero_floor']:.1f}), "
            f"validation NCC {ncc:.3f}"
        )


def train_model(ctx: Context, design: Any, stack: Any, settings: TrainSettings) -> TrainedModel:
    """Train ``settings.model`` on ``stack`` (the studio's full PSF stack of ``design``), on this thread.

    With ``settings.optics_jitter`` > 0 the jittered designs are drawn from ``design`` (their PSF
    stacks are simulated first); a ``design`` that is not a
    :class:`~lfm_studio.engine.design.Design` is the engine's ValueError naming the option.
    """
    from lfm_studio.engine.learned import TrainingDataSpec, stack_identity, train
    from lfm_studio.engine.simulation import imaging_setup

    ctx.progress(0, 1, "training: building the projector")
    setup = imaging_setup(stack)
    design_hash, depths = stack_identity(stack)
    data = TrainingDataSpec(phantoms=settings.phantoms, photons=settings.photons, seed=settings.seed,  # type: ignore[arg-type]
                            optics_jitter=settings.optics_jitter)  # fmt: skip

    def on_step(step: int, loss: float, validation: float) -> None:
        ctx.partial((step, loss, validation))

    def progress(done: int, total: int, message: str) -> None:
        ctx.progress(done, total, f"training: {message}")

    result = train(
        setup, model=settings.model, data=data, budget_minutes=settings.minutes, max_steps=settings.max_steps,
        seed=settings.seed, design_hash=design_hash, depths=depths, design=design, threads=settings.threads,
        progress=progress, cancel=ctx.cancel, on_step=on_step,
    )  # fmt: skip
    return TrainedModel(result, design, settings)


def save_trained(trained: TrainedModel, path: str | Path, *, overwrite: bool = False) -> Path:
    """Write ``trained`` as a checkpoint (atomic; an existing file only with ``overwrite``)."""
    from lfm_studio.engine.learned import save_checkpoint

    target = Path(path).expanduser()
    if target.suffix != ".safetensors":
        target = target.with_name(target.name + ".safetensors")
    return save_checkpoint(target, trained.result.model, trained.result.header, overwrite=overwrite)


@dataclass(frozen=True)
class Comparison:
    """Richardson-Lucy and the learned model on the same image, each scored against its phantom."""

    rl: ReconstructionResult
    learned: ReconstructionResult


def compare_with_rl(
    ctx: Context, design: Any, image: ImageResult, settings: WorkflowSettings, checkpoint: str
) -> Comparison:
    """The studio's image reconstructed by the default registry method and by ``checkpoint``."""
    from lfm_studio.engine.reconstruct import default_method

    if image.ground_truth is None:
        raise ValueError(
            "the current image has no phantom to score against (a measured frame). "
            "Fix: simulate an image in the 'Simulate and reconstruct' tab."
        )
    rl_settings = replace(settings, method=default_method(), method_options=())
    learned_settings = replace(settings, method="learned", method_options=(("model", str(checkpoint)),))
    rl = reconstruct(ctx, design, image, rl_settings)
    ctx.check()
    learned = reconstruct(ctx, design, image, learned_settings)
    return Comparison(rl, learned)


SCORE_ROWS = (("ncc", "NCC"), ("f1", "bead F1"), ("psnr_db", "PSNR (dB)"), ("ssim", "SSIM"))


def _text(value: float | None, key: str) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    return f"{value:.2f}" if key == "psnr_db" else f"{value:.3f}"


def comparison_rows(comparison: Comparison) -> list[tuple[str, str, str, str]]:
    """``(score, RL, learned, all-zero volume)`` rows as text, for the scores both sides have."""
    rows = []
    for key, label in SCORE_ROWS:
        left = comparison.rl.scores.score(key) if comparison.rl.scores is not None else None
        right = comparison.learned.scores.score(key) if comparison.learned.scores is not None else None
        if left is None or right is None:
            continue
        floor = left.floors.get("zero")
        rows.append((label, _text(left.value, key), _text(right.value, key), _text(floor, key)))
    return rows


def running_mean(values: list[float], window: int) -> list[float]:
    """Mean of the last ``window`` values (fewer at the start) at each position."""
    out, total = [], 0.0
    for i, value in enumerate(values):
        total += value
        if i >= window:
            total -= values[i - window]
        out.append(total / min(i + 1, window))
    return out
