"""Training a learned reconstructor from a design's own forward model.

:func:`train` draws training samples one per step (:mod:`.data`, train split), fits with Adam
on :func:`~.losses.training_loss`, scores a fixed validation set (validation split, disjoint
seeds) every ``validate_every`` steps, keeps the best weights, and stops at ``max_steps``, at
the time budget, after ``patience`` validations without improvement, or when cancelled
(then the best weights so far are returned and the checkpoint on disk is the last good one).
Torch runs on ``threads`` threads during training (default 1: small convolutions ran 5-40x
slower on 2 threads on the 2-core development machine, docs/platform.md) and the caller's
setting is restored afterwards.

With ``data.optics_jitter`` > 0 (optics-mismatch augmentation, :mod:`.mismatch`) the run
first simulates a pool of ``data.jitter_designs`` jittered designs from ``design`` (drawn from
``data.seed``) and images every training sample through one of them; the model keeps the
nominal projector, and validation stays on the nominal design unless ``data.jitter_validation``.

A run that ends with a trivial model (all-zero, constant or non-finite output on the
validation set), or with a validation loss not below the all-zero volume's, is refused with a
ValueError and writes no checkpoint (a checkpoint is written during the run only for weights below
that floor). A step whose loss is not finite is skipped (its gradients would make every weight NaN).
"""

from __future__ import annotations

import copy
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import torch

from lfm_studio.engine.image_quality import ncc
from lfm_studio.engine.learned.checkpoint import (
    CheckpointHeader,
    check_architecture,
    header_for,
    read_checkpoint,
    save_checkpoint,
)
from lfm_studio.engine.learned.data import Sample, TrainingDataSpec, make_sample, make_samples
from lfm_studio.engine.learned.losses import require_not_trivial, training_loss, trivial_reason
from lfm_studio.engine.learned.mismatch import (
    POOL_SEED_OFFSET,
    MismatchPool,
    mismatch_pool,
    require_design_for_jitter,
)
from lfm_studio.engine.learned.models import (
    DEFAULT_MODEL,
    build_model,
    model_config,
    model_options,
    parameter_count,
)
from lfm_studio.engine.progress import CancelledError, CancelToken, ProgressCallback, is_cancelled
from lfm_studio.engine.simulation import ImagingSetup
from lfm_studio.engine.threads import torch_threads
from lfm_studio.engine.types import JSONValue


@dataclass
class TrainingResult:
    """A trained model and how it got there.

    Attributes
    ----------
    model : the model with its best validation weights, in eval mode.
    header : the checkpoint header (also written when ``checkpoint`` was given).
    history : ``(step, training loss, validation loss or NaN)`` per step.
    stop_reason : "steps", "time budget", "early stopping" or "cancelled".
    """

    model: torch.nn.Module
    header: CheckpointHeader
    history: list[tuple[int, float, float]] = field(default_factory=list)
    stop_reason: str = ""


def validation_loss(model: torch.nn.Module, samples: list[Sample], high_pass_weight: float) -> float:
    """Mean :func:`training_loss` of ``model`` over ``samples`` (no gradients)."""
    with torch.no_grad():
        losses = [float(training_loss(model(s.image), s.truth, high_pass_weight)) for s in samples]
    return sum(losses) / len(losses)


def validation_ncc(model: torch.nn.Module, samples: list[Sample]) -> float:
    """Mean normalised cross-correlation of ``model``'s volumes with the truths (1 = perfect, 0 = unrelated)."""
    with torch.no_grad():
        values = [float(ncc(s.truth, require_not_trivial(model(s.image), "the trained model's output")))
                  for s in samples]  # fmt: skip
    return sum(values) / len(values)


def train(
    setup: ImagingSetup,
    *,
    model: str = DEFAULT_MODEL,
    config: dict[str, JSONValue] | None = None,
    data: TrainingDataSpec | None = None,
    budget_minutes: float = 10.0,
    max_steps: int | None = None,
    learning_rate: float = 1e-3,
    high_pass_weight: float = 1.0,
    validation_size: int = 8,
    validate_every: int = 10,
    patience: int = 10,
    seed: int = 0,
    design_hash: str | None = None,
    depths: tuple[float, ...] = (),
    design: object = None,
    checkpoint: str | os.PathLike | None = None,
    resume: bool = False,
    overwrite: bool = False,
    threads: int = 1,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    clock: Callable[[], float] = time.monotonic,
    on_step: Callable[[int, float, float], None] | None = None,
) -> TrainingResult:
    """Train ``model`` for ``setup`` (an :class:`~lfm_studio.engine.simulation.ImagingSetup`).

    Parameters
    ----------
    model, config : model name and keyword config (:func:`~.models.build_model`).
    data : training data spec (default :class:`TrainingDataSpec` with ``seed``).
    budget_minutes : wall-clock budget (the run stops after the step that crosses it).
    max_steps : stop after this many steps (deterministic runs: tests, benchmarks).
    validate_every, validation_size, patience : validation schedule and early stopping.
    design_hash, depths : what the checkpoint header records (the design's optics hash, PSF depths in m).
    design : the design ``setup`` was simulated from; needed only for ``data.optics_jitter`` > 0
        (a ValueError naming the option otherwise, e.g. when training from a bare PSF stack).
    checkpoint : file to write the best model to (atomic; refused if it exists, unless
        ``overwrite`` or ``resume``); with ``resume`` its weights and step count are the start.
    threads : torch threads during training.
    progress, cancel : ``progress(step, total, message)`` and a cancel token.
    on_step : called after every step with ``(step, training loss, validation loss or NaN)``
        (a live loss curve; runs on the training thread).
    """
    if not (budget_minutes > 0 and math.isfinite(budget_minutes)):
        raise ValueError(f"budget_minutes must be a positive number of minutes; got {budget_minutes!r}.")
    if max_steps is not None and not (isinstance(max_steps, int) and max_steps >= 1):
        raise ValueError(f"max_steps must be an integer >= 1 or None; got {max_steps!r}.")
    data = data if data is not None else TrainingDataSpec(seed=seed)
    jitter_design = require_design_for_jitter(design, data.optics_jitter)
    target = Path(checkpoint).expanduser() if checkpoint is not None else None
    if target is not None and target.exists() and not (overwrite or resume):
        raise FileExistsError(
            f"--out {target} already exists. Fix: pass --overwrite, --resume, or another name."
        )
    with torch_threads(threads):
        torch.manual_seed(seed)
        previous_run = read_checkpoint(target) if resume and target is not None and target.exists() else None
        if previous_run is not None and previous_run[0].model != model:
            raise ValueError(f"--resume: {target} holds a {previous_run[0].model!r} model, not {model!r}.")
        # A resumed run keeps the checkpoint's config unless one is given (older ones lack the data options).
        if previous_run is not None and config is None:
            options = dict(previous_run[0].config)
        else:
            options = _with_data_options(model, config, data)
        network = build_model(model, setup.projector, **options)
        pool = None
        if jitter_design is not None:
            if progress is not None:
                progress(
                    0, 0, f"simulating {data.jitter_designs} jittered designs (jitter {data.optics_jitter:g})"
                )
            pool = mismatch_pool(jitter_design, data.optics_jitter, count=data.jitter_designs,
                                 seed=data.seed + POOL_SEED_OFFSET)  # fmt: skip
        start, best, best_step = 0, math.inf, 0
        if previous_run is not None:
            previous, tensors = previous_run
            check_architecture(previous, str(target), setup.projector)
            if previous.config != model_config(network):
                now = model_config(network)
                differs = sorted(k for k in {*previous.config, *now} if previous.config.get(k) != now.get(k))
                raise ValueError(
                    f"--resume: {target} holds a {model!r} model with config {previous.config}, not "
                    f"{now} (differs in {', '.join(differs)}). Fix: resume with the same model config (or "
                    "without --config, to keep the checkpoint's), or train afresh."
                )
            network.load_state_dict(tensors)
            steps, best_validation = (
                previous.training.get("steps", 0),
                previous.training.get("best_validation", math.inf),
            )
            if not (isinstance(steps, (int, float, str)) and isinstance(best_validation, (int, float, str))):
                raise ValueError(
                    f"--resume: {target} has no readable step count and validation loss in its header."
                )
            start, best = int(steps), float(best_validation)
            recorded = previous.training.get("best_step", start)
            best_step = int(recorded) if isinstance(recorded, (int, float)) else start
        loop = _Loop(
            network, setup, data, model_name=model, design_hash=design_hash, depths=depths, seed=seed,
            high_pass_weight=high_pass_weight, validation_size=validation_size, target=target, pool=pool,
        )  # fmt: skip
        history, reason = loop.run(
            start=start, best=best, best_step=best_step, budget_s=60.0 * budget_minutes, max_steps=max_steps,
            learning_rate=learning_rate, validate_every=validate_every, patience=patience,
            progress=progress, cancel=cancel, clock=clock, on_step=on_step,
        )  # fmt: skip
        if reason == "cancelled":
            raise CancelledError(
                "training cancelled (the checkpoint file holds the last validated best, if any)"
            )
        header = loop.finish(history[-1][0] if history else start, reason)
    return TrainingResult(network, header, history, reason)


def _with_data_options(
    model: str, config: dict[str, JSONValue] | None, data: TrainingDataSpec
) -> dict[str, JSONValue]:
    """``config`` plus what the training data say about the camera, for models that take it: the
    read noise (``read_noise``, photo-electrons rms) unless ``config`` sets it."""
    options = model_options(model) or ()
    extra: dict[str, JSONValue] = {"read_noise": data.read_noise} if "read_noise" in options else {}
    return {**extra, **(config or {})}


class _Loop:
    """One training run's state: the network, its validation set and the checkpoint it writes."""

    def __init__(self, network: torch.nn.Module, setup: ImagingSetup, data: TrainingDataSpec, *, model_name: str,
                 design_hash: str | None, depths: tuple[float, ...], seed: int, high_pass_weight: float,
                 validation_size: int, target: Path | None, pool: MismatchPool | None = None) -> None:  # fmt: skip
        self.network, self.setup, self.data, self.pool = network, setup, data, pool
        self.model_name, self.design_hash, self.depths, self.seed = model_name, design_hash, depths, seed
        self.high_pass_weight, self.target = high_pass_weight, target
        validation_imaging = pool if data.jitter_validation else None
        self.validation = make_samples(data, setup, "validation", validation_size, imaging=validation_imaging)
        self.best, self.best_step = math.inf, 0
        self.best_state = copy.deepcopy(network.state_dict())
        self.seconds = 0.0
        self.zero_floor = 1.0 + high_pass_weight  # the all-zero volume's loss (losses.training_loss)

    def run(self, *, start: int, best: float, best_step: int, budget_s: float, max_steps: int | None, learning_rate: float,
            validate_every: int, patience: int, progress: ProgressCallback | None, cancel: CancelToken,
            clock: Callable[[], float], on_step: Callable[[int, float, float], None] | None = None,
            ) -> tuple[list[tuple[int, float, float]], str]:  # fmt: skip
        """Steps until ``max_steps``, the budget, early stopping or cancel; returns (history, stop reason).

        ``best`` / ``best_step``: the validation loss to beat and the step its weights come from
        (a resumed checkpoint's). When the budget ends the run, the steps since the last
        validation are validated once more, so no trained step is dropped unscored.
        """
        network = self.network
        optimiser = torch.optim.Adam(network.parameters(), lr=learning_rate)
        history: list[tuple[int, float, float]] = []
        began, since_best, reason, step = clock(), 0, "steps", start
        self.best, self.best_step = best, best_step
        if math.isinf(best):  # the starting point is the first candidate: training never ends worse
            self.network.eval()
            self.best = validation_loss(network, self.validation, self.high_pass_weight)
        # progress counts steps when they are capped, else the seconds of the budget spent
        total = max_steps if max_steps is not None else max(round(budget_s), 1)
        while max_steps is None or step - start < max_steps:
            if clock() - began >= budget_s:
                reason = "time budget"
                if history and math.isnan(history[-1][2]):  # the steps since the last validation count too
                    checked = self._validate(step, clock() - began)
                    history[-1] = (history[-1][0], history[-1][1], checked)
                break
            if is_cancelled(cancel):
                reason = "cancelled"
                break
            sample = make_sample(self.data, self.setup, "train", step, imaging=self.pool)
            network.train()
            optimiser.zero_grad()
            loss = training_loss(network(sample.image), sample.truth, self.high_pass_weight)
            value = float(loss.detach())
            if math.isfinite(value):  # a non-finite loss or gradient would turn every weight into NaN: skip
                loss.backward()
                if all(p.grad is None or bool(torch.isfinite(p.grad).all()) for p in network.parameters()):
                    optimiser.step()
            step += 1
            checked = math.nan
            if (step - start) % validate_every == 0 or step - start == max_steps:
                checked = self._validate(step, clock() - began)
                since_best = 0 if checked <= self.best else since_best + 1
            history.append((step, value, checked))
            if on_step is not None:
                on_step(step, value, checked)
            if progress is not None:
                shown = "" if math.isnan(checked) else f", validation {checked:.4f}"
                done = step - start if max_steps is not None else min(round(clock() - began), total)
                progress(done, total, f"step {step}: loss {value:.4f}{shown}")
            if since_best >= patience:
                reason = "early stopping"
                break
        self.seconds = clock() - began
        return history, reason

    def _validate(self, step: int, seconds: float) -> float:
        """Validation loss now; a new best is kept (and checkpointed when it is not trivial)."""
        self.network.eval()
        checked = validation_loss(self.network, self.validation, self.high_pass_weight)
        if checked < self.best:
            self.best, self.best_step = checked, step
            self.best_state = copy.deepcopy(self.network.state_dict())
            if (
                self.target is not None
                and checked < self.zero_floor
                and trivial_reason(self.network(self.validation[0].image).detach()) is None
            ):
                save_checkpoint(
                    self.target, self.network, self._header(step, seconds, "running"), overwrite=True
                )
        return checked

    def _header(
        self, steps: int, seconds: float, reason: str, metrics: dict[str, JSONValue] | None = None
    ) -> CheckpointHeader:
        training: dict[str, JSONValue] = {"steps": steps, "seconds": seconds, "seed": self.seed, "best_validation": self.best,
                    "best_step": self.best_step, "stop_reason": reason, "parameters": parameter_count(self.network),
                    "zero_floor": self.zero_floor}  # fmt: skip
        return header_for(self.model_name, model_config(self.network), self.setup, self.design_hash, self.depths,
                          data=self.data.to_dict(), training=training, metrics=metrics or {})  # fmt: skip

    def finish(self, steps: int, reason: str) -> CheckpointHeader:
        """Best weights back in the network, refuse a trivial model, write the final checkpoint."""
        self.network.load_state_dict(self.best_state)
        self.network.eval()
        if math.isinf(self.best):
            self.best = validation_loss(self.network, self.validation, self.high_pass_weight)
        score = validation_ncc(self.network, self.validation)  # refuses a trivial model
        if not self.best < self.zero_floor:
            raise ValueError(
                f"the trained model's validation loss {self.best:.4g} is not below the all-zero volume's "
                f"{self.zero_floor:g}: it reconstructs worse than predicting nothing, so no model was written. "
                "Fix: more photons per image (--photons), a longer run (--minutes / --steps), or the "
                "physics-based model (--model unrolled-rl)."
            )
        header = self._header(steps, self.seconds, reason, {"validation_ncc": score})
        if self.target is not None:
            save_checkpoint(self.target, self.network, header, overwrite=True)
        return header
