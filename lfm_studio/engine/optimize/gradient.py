"""Gradient optimisation of a design (thesis 5.2.2 PSF engineering; 5.3.2 end to end in :mod:`.end_to_end`).

:func:`optimize_psf` descends a differentiable PSF-engineering objective (b) through the
per-lenslet Fourier fast path, or the conventional-LFM patterns (:mod:`.gradient_params` lists
the parameters it can free for each):

- **optimiser**: ``"adam"`` (:class:`torch.optim.Adam`) or ``"lbfgs"``
  (:class:`torch.optim.LBFGS` with ``max_iter=1``: one evaluation per step, the curvature
  history kept across steps; no line search, so every step evaluates once);
- **variables**: ``u`` in ``[0, 1]`` per parameter (``value = low + (high - low) u``), so one
  learning rate fits parameters in mm, um and unitless alike (``lr`` is a fraction of each
  parameter's range per step, for Adam roughly the step length);
- **schedule** (:data:`SCHEDULES`): a factor on ``lr`` per step, ``constant``, ``cosine`` (to 5 %),
  ``exponential`` (to 10 %) or ``step`` (halved every third of the run);
- **projection** after each step: ``u`` clamped to ``[0, 1]`` (the bounds). The other
  constraints (the design's own checks and ``constraints``, default
  :func:`.constraints.default_constraints`) are not a box: a step that breaks one is
  backtracked, halving it towards the last feasible point up to :data:`BACKTRACKS` times; when
  none is feasible each parameter's move is tried alone and kept if feasible (sliding along
  the boundary), and the backtracking is recorded (``gradient.backtracks``, ``backtrack_reason``);
- **catalogue**: focal lengths descend continuously within their bounds; with a
  :class:`.constraints.FocalLengthCatalogue` the final design is snapped to the nearest stock
  values at the end and evaluated again (``snapped_value`` next to ``final_value``);
- **precision**: the run computes in ``settings.dtype`` (default float32; ``"float64"`` to run
  in double); :func:`precision_check` compares the start gradient in float32 with float64
  (relative L2 difference, :data:`GRADIENT_TOLERANCE`), stored in the result and the study.

Each step can be recorded into a stored study (:class:`.gradient_study.GradientStudy`; one
trial per step, ``lfm-studio study show`` lists it).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.design_io import design_to_json
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.design.space import DesignSpace
from lfm_studio.engine.optimize import psf_losses
from lfm_studio.engine.optimize.candidate import EvaluationSettings
from lfm_studio.engine.optimize.constraints import (
    Constraint,
    FocalLengthCatalogue,
    Infeasible,
    default_constraints,
    first_violation,
    infeasible_from_error,
)
from lfm_studio.engine.optimize.gradient_params import SpaceBinding, bind_space
from lfm_studio.engine.optimize.gradient_study import GradientStudy
from lfm_studio.engine.optimize.objectives import PSFLoss, objective_named, score_options, sign
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint

OPTIMIZERS: tuple[str, ...] = ("adam", "lbfgs")
SCHEDULES: tuple[str, ...] = ("constant", "cosine", "exponential", "step")
BACKTRACKS = 6
GRADIENT_TOLERANCE = 1e-3
"""Default bound of ``|g32 - g64| / |g64|`` for the start gradient (see :func:`precision_check`)."""

LossFunction = Callable[[torch.Tensor, str], torch.Tensor]
"""``loss(u, dtype_name) -> 0-d tensor`` (minimised), differentiable in ``u``."""


def schedule_factor(name: str, step: int, steps: int) -> float:
    """The learning-rate factor of ``schedule`` ``name`` at ``step`` of ``steps`` (1 at step 0)."""
    t = step / max(1, steps)
    if name == "constant":
        return 1.0
    if name == "cosine":
        return 0.05 + 0.95 * 0.5 * (1.0 + math.cos(math.pi * t))
    if name == "exponential":
        return 0.1**t
    if name == "step":
        return 0.5 ** (step // max(1, math.ceil(steps / 3)))
    raise ValueError(f"schedule must be one of {SCHEDULES}; got {name!r}.")


def make_optimizer(name: str, groups: list[dict[str, Any]]) -> torch.optim.Optimizer:
    """Adam over the parameter groups, or L-BFGS (one group: its parameters, the first group's ``lr``)."""
    if name == "adam":
        return torch.optim.Adam(groups)
    if name == "lbfgs":
        params = [p for g in groups for p in g["params"]]
        return torch.optim.LBFGS(params, lr=groups[0]["lr"], max_iter=1, history_size=10)
    raise ValueError(f"optimizer must be one of {OPTIMIZERS}; got {optimizer_hint(name)}.")


def optimizer_hint(name: str) -> str:
    return f"{name!r}. Fix: 'adam' (robust) or 'lbfgs' (smooth, few parameters)"


@dataclass(frozen=True)
class PrecisionCheck:
    """Start gradient in float32 against float64: ``relative_error = |g32 - g64| / |g64|`` (L2).
    An all-zero float64 gradient fails (``relative_error`` inf): a flat objective says nothing
    about precision, and a descent from there cannot move."""

    relative_error: float
    tolerance: float
    gradient_float32: tuple[float, ...]
    gradient_float64: tuple[float, ...]

    @property
    def passed(self) -> bool:
        return self.relative_error <= self.tolerance

    def to_dict(self) -> dict[str, Any]:
        return {
            "relative_error": self.relative_error,
            "tolerance": self.tolerance,
            "passed": self.passed,
            "gradient_float32": list(self.gradient_float32),
            "gradient_float64": list(self.gradient_float64),
        }


DTYPES: tuple[str, ...] = ("float32", "float64")
"""The precisions a gradient run computes in (``dtype``)."""

PrecisionLoss = Callable[[str], tuple[torch.Tensor, Sequence[torch.Tensor]]]
"""``loss(dtype_name) -> (loss, leaves)``: the start loss in that precision and the leaf tensors
whose gradients the precision check compares (fresh leaves per call)."""


def check_dtype(dtype: str) -> None:
    """Refuse a ``dtype`` that is not one of :data:`DTYPES`."""
    if dtype not in DTYPES:
        raise ValueError(f"dtype must be 'float32' or 'float64'; got {dtype!r}.")


def flat_gradient(leaves: Sequence[torch.Tensor], grads: Sequence[torch.Tensor | None]) -> torch.Tensor:
    """The gradients of ``leaves`` as one flat float64 vector (zeros for a leaf without one)."""
    flat = [torch.zeros_like(x) if g is None else g for x, g in zip(leaves, grads, strict=True)]
    return torch.cat([g.detach().reshape(-1).to(torch.float64) for g in flat])


def gradient_in(loss: PrecisionLoss, dtype: str) -> torch.Tensor:
    """The flat float64 gradient (:func:`flat_gradient`) of ``loss(dtype)`` over its leaves."""
    value, leaves = loss(dtype)
    return flat_gradient(leaves, torch.autograd.grad(value, list(leaves), allow_unused=True))


def precision_check(
    loss: PrecisionLoss,
    tolerance: float = GRADIENT_TOLERANCE,
    *,
    known: Mapping[str, torch.Tensor] | None = None,
) -> PrecisionCheck:
    """Compare the gradient in float32 with float64. ``loss(dtype_name)`` returns the loss and the
    leaf tensors whose gradients are compared (fresh leaves per call); ``known`` maps a dtype name
    to its flat gradient when it was computed already (that precision is then not evaluated)."""
    known = known or {}
    g32, g64 = (known[d] if d in known else gradient_in(loss, d) for d in DTYPES)
    scale = float(g64.norm())
    error = float((g32 - g64).norm()) / scale if scale > 0 else math.inf
    return PrecisionCheck(error, tolerance, tuple(g32.tolist()), tuple(g64.tolist()))


@dataclass(frozen=True)
class StepRecord:
    """One step: the point evaluated (design values), its objective ``value`` and minimised ``loss``,
    ``grad_norm`` (of the normalised ``u`` and any reconstruction weights), the learning rate,
    seconds, and how often the update was halved to stay feasible."""

    step: int
    point: dict[str, float]
    value: float
    loss: float
    grad_norm: float
    lr: float
    seconds: float
    backtracks: int = 0
    infeasible: str | None = None


FINAL_VALUE_AT: tuple[str, ...] = ("final_point", "before_last_update")
"""Where :attr:`GradientResult.final_value` was measured: at the final design's point (PSF
engineering), or at the last step's point before its update (end to end: a training loss)."""


@dataclass
class GradientResult:
    """What a gradient run returns.

    design : the final design (written through the space's ``apply``; snapped when a catalogue is given).
    start_design : the (bound-projected) start.
    history : one :class:`StepRecord` per step.
    start_value, final_value : the objective at the start and, where :attr:`final_value_at` is
        ``"final_point"``, at the final (unsnapped) point; end to end (``"before_last_update"``)
        ``final_value`` is the last step's training loss, measured at the point *before* that
        step's update: nothing was measured on training batches at the final design (its value
        there is ``extra["held_out_final"]``, the held-out loss).
    final_value_at : where ``final_value`` was measured, one of :data:`FINAL_VALUE_AT`.
    snapped_value : the objective after snapping to the catalogue (None without one).
    unsnapped_design : the final design before snapping.
    check : the float32 / float64 start-gradient comparison (None when not asked).
    study : the stored ``optuna.Study`` (None when not recorded).
    final : "best" (the design is the best evaluated point: a step or the last point) or "last".
    final_point : the point of :attr:`design` before snapping (design units).
    last_value, last_point : the objective and point after the last update.
    resumed_from : the steps a resumed study held (0 for a fresh run); :attr:`history` holds them too.
    extra : end-to-end numbers (held-out losses, the floor; see :mod:`.end_to_end`).
    model : the trained reconstruction of an end-to-end run (None otherwise).
    warnings : the design warnings of :attr:`design` (caught during the run, not emitted).
    """

    design: Design
    start_design: Design
    history: list[StepRecord]
    start_value: float
    final_value: float
    snapped_value: float | None = None
    unsnapped_design: Design | None = None
    check: PrecisionCheck | None = None
    study: Any = None
    extra: dict[str, Any] = field(default_factory=dict)
    model: Any = None
    warnings: list[str] = field(default_factory=list)
    final: str = "last"
    final_point: dict[str, float] | None = None
    last_value: float | None = None
    last_point: dict[str, float] | None = None
    resumed_from: int = 0
    final_value_at: str = "final_point"

    @property
    def best(self) -> StepRecord | None:
        """The step with the lowest loss (the objective's best among the steps)."""
        finite = [h for h in self.history if math.isfinite(h.loss)]
        return min(finite, key=lambda h: h.loss) if finite else None

    def summary(self) -> dict[str, Any]:
        """JSON-ready numbers (stored as the study's ``gradient`` attribute)."""
        return {
            "steps": len(self.history),
            "start_value": self.start_value,
            "final_value": self.final_value,
            "final_value_at": self.final_value_at,
            "snapped_value": self.snapped_value,
            "check": None if self.check is None else self.check.to_dict(),
            "final": self.final,
            "final_point": self.final_point,
            "last_value": self.last_value,
            "last_point": self.last_point,
            "resumed_from": self.resumed_from,
            "best_step": None if self.best is None else self.best.step,
            "warnings": list(self.warnings),
            **self.extra,
        }


# ---------------------------------------------------------------------------------------------
# Objectives (b) in differentiable form


@dataclass(frozen=True)
class SoftMTFSupportLoss:
    """Mean over depths of the MTF support fraction with a sigmoid step of width ``softness``
    (:func:`.psf_losses.mtf_support`): the differentiable form of the ``mtf_support`` objective."""

    threshold: float = 0.1
    band: float = 0.5
    softness: float = 0.02

    def __call__(self, stack: Any) -> torch.Tensor:
        data = torch.as_tensor(stack.data)
        flat = data.reshape(-1, *data.shape[-3:])
        return torch.stack(
            [
                psf_losses.mtf_support(
                    p, threshold=self.threshold, band=self.band, softness=self.softness
                ).mean()
                for p in flat
            ]
        ).mean()


PSF_OBJECTIVES: tuple[str, ...] = ("axial_crb", "depth_dissimilarity", "mtf_support")


def psf_objective(objective: str | PSFLoss, options: Mapping[str, Any] | None = None) -> PSFLoss:
    """A differentiable PSF-engineering objective: a name of :data:`PSF_OBJECTIVES` (``mtf_support``
    in its soft form, ``options["softness"]``, default 0.02) or a :class:`PSFLoss` (whose loss
    must be differentiable in the stack)."""
    if isinstance(objective, PSFLoss):
        return objective
    options = dict(options or {})
    if objective == "mtf_support":
        return PSFLoss(
            "mtf_support", SoftMTFSupportLoss(softness=float(options.get("softness", 0.02))), "", "maximize"
        )
    if objective not in PSF_OBJECTIVES:
        raise ValueError(
            f"gradient PSF engineering needs a differentiable PSF objective, one of {PSF_OBJECTIVES}; got "
            f"{objective!r}. Fix: pick one of those (closed-form and task objectives have no gradient here; "
            "use --gradient end-to-end for the task loss)."
        )
    built = objective_named(objective, options)
    assert isinstance(built, PSFLoss)
    return built


# ---------------------------------------------------------------------------------------------
# The descent loop (shared with the end-to-end optimiser)


def quietly(build: Callable[[], Design]) -> tuple[Design, list[str]]:
    """``build()`` with its design warnings caught and returned (each once), not emitted: a
    descent validates a design at every step, the warnings go into the records instead."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DesignWarning)
        design = build()
    notes = [str(w.message) for w in caught if issubclass(w.category, DesignWarning)]
    for w in caught:
        if not issubclass(w.category, DesignWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return design, list(dict.fromkeys(notes))


def _feasible(
    binding: SpaceBinding, design: Design, u: torch.Tensor, constraints: Sequence[Constraint]
) -> tuple[Design | None, Infeasible | None]:
    _, point = binding.values_and_point(u)
    try:
        candidate, _ = design_at(binding, design, point)
    except ValueError as error:
        return None, infeasible_from_error(error)
    found = first_violation(candidate, constraints)
    return (None, found) if found is not None else (candidate, None)


@dataclass
class DescentSetup:
    """What :func:`descend` needs besides the loss: the optics, optimiser and records."""

    binding: SpaceBinding
    design: Design
    steps: int
    optimizer: str = "adam"
    lr: float = 0.05
    schedule: str = "constant"
    constraints: Sequence[Constraint] = ()
    freeze_optics: bool = False
    extra_groups: list[dict[str, Any]] = field(default_factory=list)
    study: GradientStudy | None = None
    progress: ProgressCallback | None = None
    cancel: CancelToken = None
    direction: str = "minimize"
    first_step: int = 0  # a resumed run continues the step numbers (and the schedule) from here
    on_first_gradient: Callable[[torch.Tensor], None] | None = None
    """Called once with the first step's first gradient, flat float64 over ``u`` (unless the optics
    are frozen) then the ``extra_groups`` parameters (:func:`flat_gradient`): the start gradient."""


def _closure(
    optimizer: torch.optim.Optimizer,
    loss_at: Callable[[torch.Tensor, int], torch.Tensor],
    u: torch.Tensor,
    step: int,
    weights: list[torch.Tensor],
    seen: dict[str, Any],
    on_gradient: Callable[[torch.Tensor], None] | None = None,
) -> Callable[[], torch.Tensor]:
    """The loss-and-gradient closure of one step; the first call's loss, point and gradient norm go
    into ``seen`` (and its flat gradient to ``on_gradient``, when given)."""

    def closure() -> torch.Tensor:
        optimizer.zero_grad()
        loss = loss_at(u, step)
        loss.backward()
        if "loss" not in seen:  # the point of this step (L-BFGS calls once with max_iter=1)
            seen["loss"] = float(loss.detach())
            seen["u"] = u.detach().clone()
            grads = [p.grad.detach().reshape(-1) for p in weights if p.grad is not None]
            seen["grad_norm"] = float(torch.cat(grads).norm()) if grads else 0.0
            if on_gradient is not None:
                on_gradient(flat_gradient(weights, [p.grad for p in weights]))
        return loss

    return closure


def _slide(setup: DescentSetup, last_good: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """After every halving failed: move the parameters one at a time, keeping each move that stays
    feasible (slides along a constraint boundary instead of stopping at it)."""
    point = last_good.clone()
    for i in range(point.numel()):
        trial = point.clone()
        trial[i] = target[i]
        if _feasible(setup.binding, setup.design, trial, setup.constraints)[1] is None:
            point = trial
    return point


def descend(
    setup: DescentSetup, u: torch.Tensor, loss_at: Callable[[torch.Tensor, int], torch.Tensor]
) -> list[StepRecord]:
    """Run ``setup.steps`` steps on ``u`` (a leaf tensor in ``[0, 1]``, updated in place) and the
    ``extra_groups`` parameters; ``loss_at(u, step)`` is the minimised loss (objective times its sign)."""
    if setup.optimizer not in OPTIMIZERS:
        raise ValueError(f"optimizer must be one of {OPTIMIZERS}; got {optimizer_hint(setup.optimizer)}.")
    schedule_factor(setup.schedule, 0, setup.steps)  # names the schedule early
    if not (isinstance(setup.steps, int) and setup.steps >= 1):
        raise ValueError(f"steps must be an integer >= 1; got {setup.steps!r}.")
    groups: list[dict[str, Any]] = [] if setup.freeze_optics else [{"params": [u], "lr": setup.lr}]
    groups += setup.extra_groups
    if not groups:
        raise ValueError("nothing to optimise: the optics are frozen and there are no other parameters.")
    for group in groups:
        group["initial_lr"] = group["lr"]
    optimizer = make_optimizer(setup.optimizer, groups)
    history: list[StepRecord] = []
    weights = [p for g in groups for p in g["params"]]
    last_good = u.detach().clone()
    for step in range(setup.first_step, setup.steps):
        checkpoint(setup.cancel, setup.progress, step, setup.steps, f"gradient step {step + 1}/{setup.steps}")
        factor = schedule_factor(setup.schedule, step, setup.steps)
        for group, source in zip(optimizer.param_groups, groups, strict=False):
            group["lr"] = source["initial_lr"] * factor
        start = time.perf_counter()
        seen: dict[str, Any] = {}
        first = step == setup.first_step
        closure = _closure(
            optimizer, loss_at, u, step, weights, seen, setup.on_first_gradient if first else None
        )
        if setup.optimizer == "lbfgs":
            optimizer.step(closure)  # type: ignore[arg-type]
        else:
            closure()
            optimizer.step()
        backtracks, reason = 0, None
        with torch.no_grad():
            projected = bool(((u < 0.0) | (u > 1.0)).any())
            u.clamp_(0.0, 1.0)  # projection onto the bounds
            if not setup.freeze_optics:
                target = u.detach().clone()
                while True:
                    _, found = _feasible(setup.binding, setup.design, u, setup.constraints)
                    if found is None:
                        break
                    reason = str(found)
                    backtracks += 1
                    if backtracks > BACKTRACKS:
                        u.copy_(_slide(setup, last_good, target))
                        break
                    u.copy_(last_good + (target - last_good) * 0.5**backtracks)
                last_good = u.detach().clone()
            if setup.optimizer == "lbfgs" and (projected or backtracks):
                # L-BFGS' curvature pairs describe the step it proposed, not the projected or
                # backtracked one that was taken: forget them rather than mislead the next steps.
                optimizer.state.clear()
        _, point = setup.binding.values_and_point(seen["u"])
        loss_value = seen["loss"]
        value = loss_value * sign(setup.direction)
        record = StepRecord(
            step,
            point,
            value,
            loss_value,
            seen["grad_norm"],
            float(optimizer.param_groups[0]["lr"]),
            time.perf_counter() - start,
            backtracks,
            reason,
        )
        history.append(record)
        if setup.study is not None:
            record_point(
                setup.study, setup.binding, setup.design, point, value, seconds=record.seconds,
                gradient={"step": step, "loss": loss_value, "grad_norm": record.grad_norm, "lr": record.lr,
                          "optimizer": setup.optimizer, "backtracks": backtracks, "backtrack_reason": reason},
            )  # fmt: skip
    checkpoint(setup.cancel, setup.progress, setup.steps, setup.steps, "gradient steps done")
    return history


def design_at(binding: SpaceBinding, design: Design, point: Mapping[str, float]) -> tuple[Design, list[str]]:
    """``design`` with the space ``point`` (design units) written in, and its design warnings
    (caught, not emitted: :func:`quietly`)."""
    return quietly(lambda: binding.space.apply(design, point))


def start_point(binding: SpaceBinding, design: Design) -> tuple[torch.Tensor, Design]:
    """``u`` of the design's values, clamped to the bounds, and the design at that point."""
    u = binding.normalised(binding.values_of(design)).clamp(0.0, 1.0)
    start, _ = design_at(binding, design, binding.values_and_point(u)[1])
    return u, start


@dataclass(frozen=True)
class Start:
    """Where a gradient run starts (:func:`prepare_start`).

    binding : the space bound to the design (:func:`.gradient_params.bind_space`).
    constraints : checked after every step (the given ones, else the design's defaults).
    u : the normalised start ``(P,)`` float64 in ``[0, 1]`` (the design's values projected on the bounds).
    design : the design at ``u`` (the bound-projected start).
    """

    binding: SpaceBinding
    constraints: tuple[Constraint, ...]
    u: torch.Tensor
    design: Design


def prepare_start(design: Design, space: DesignSpace, constraints: Sequence[Constraint] | None) -> Start:
    """Bind ``space`` to ``design``, project the start on the bounds and refuse an infeasible start
    (``ValueError`` naming the violated constraint)."""
    binding = bind_space(space, design)
    checks = default_constraints(design) if constraints is None else tuple(constraints)
    u0, start_design = start_point(binding, design)
    _, found = _feasible(binding, design, u0, checks)
    if found is not None:
        raise ValueError(f"the start design is infeasible ({found}). Fix: start from a feasible design.")
    return Start(binding, checks, u0, start_design)


class StartGradientCheck:
    """The float32 / float64 start-gradient comparison (:func:`precision_check`) of a descent in
    ``dtype``, sharing its work with the descent.

    The start gradient in ``dtype`` is the descent's first gradient (same point, same loss), so
    with ``reuse`` (the descent differentiates exactly the check's leaves, in the same order) only
    the other precision is evaluated here: pass :meth:`take` as ``DescentSetup.on_first_gradient``
    and read :meth:`result` after the descent. Without ``reuse`` both precisions are evaluated now.
    The other precision is always evaluated now, at the start weights (before the descent moves them).
    """

    def __init__(self, loss: PrecisionLoss, dtype: str, tolerance: float, *, reuse: bool) -> None:
        self.loss, self.dtype, self.tolerance, self.reuse = loss, dtype, tolerance, reuse
        self.known = {d: gradient_in(loss, d) for d in DTYPES if d != dtype or not reuse}

    def take(self, gradient: torch.Tensor) -> None:
        """The descent's first gradient (flat float64), when reused."""
        if self.reuse:
            self.known[self.dtype] = gradient.clone()

    def result(self) -> PrecisionCheck:
        """The comparison (evaluates the descent's precision only if the descent did not provide it)."""
        return precision_check(self.loss, self.tolerance, known=self.known)


def open_recorder(
    study: str | None,
    study_name: str,
    *,
    design: Design,
    space: DesignSpace,
    objective: Mapping[str, str],
    run_settings: EvaluationSettings,
    options: Mapping[str, Any],
    seed: int,
    resume: bool = False,
    objective_options: Mapping[str, Any] | None = None,
) -> GradientStudy | None:
    """The study a gradient run records into (None without a ``study`` database): sampler
    ``gradient-<options["optimizer"]>``, settings :func:`study_settings` of ``run_settings`` and ``options``;
    ``objective_options``: the objective's score options (compared on resume)."""
    if study is None:
        return None
    return GradientStudy(
        study, design=design, space=space, objective=objective,
        settings=study_settings(run_settings, **options), sampler=f"gradient-{options['optimizer']}",
        seed=seed, study_name=study_name, resume=resume, options=objective_options,
    )  # fmt: skip


def record_point(
    recorder: GradientStudy,
    binding: SpaceBinding,
    design: Design,
    point: Mapping[str, float],
    value: float,
    *,
    seconds: float,
    gradient: Mapping[str, Any],
) -> None:
    """Store one evaluated point (a step, or the last point) with the design JSON there and its warnings."""
    at, notes = design_at(binding, design, point)
    recorder.add(point, value, design_to_json(at), seconds=seconds, warnings=notes, gradient=gradient)


def snap_result(
    result: GradientResult,
    binding: SpaceBinding,
    catalogue: FocalLengthCatalogue | None,
    score: Callable[[torch.Tensor, Design], float],
) -> None:
    """Snap ``result.design`` to ``catalogue`` (nothing without one): the snapped design becomes
    ``result.design`` (the unsnapped one ``unsnapped_design``), ``snapped_value`` is ``score(values,
    snapped)`` (``values``: the snapped design's ``(P,)`` float64 values at the space's paths) and
    ``warnings`` the snapped design's."""
    if catalogue is None:
        return
    chosen = result.design
    snapped, notes = quietly(lambda: catalogue.snap(chosen))
    result.snapped_value = score(binding.values_of(snapped), snapped)
    result.unsnapped_design, result.design, result.warnings = chosen, snapped, notes


def finish_study(result: GradientResult, recorder: GradientStudy | None) -> GradientResult:
    """Store the run summary in the study (when recorded) and attach the study to ``result``."""
    if recorder is not None:
        recorder.finish(result.summary())
        result.study = recorder.study
    return result


def study_settings(settings: EvaluationSettings, **options: Any) -> dict[str, Any]:
    """The study's ``settings`` attribute (compared on resume; the step count is not part of it, so
    a resumed run may ask for more steps)."""
    return {**settings.to_dict(), "gradient": {k: v for k, v in options.items() if k != "steps"}}


FINALS: tuple[str, ...] = ("best", "last")


def step_from_trial(params: Mapping[str, float], value: float, record: Mapping[str, Any]) -> StepRecord:
    """A stored gradient trial as a :class:`StepRecord`."""
    g = record["gradient"]
    return StepRecord(
        int(g["step"]), dict(params), value, float(g["loss"]), float(g["grad_norm"]), float(g["lr"]),
        float(record.get("timing", {}).get("total_s", 0.0)), int(g.get("backtracks", 0)), g.get("backtrack_reason"),
    )  # fmt: skip


def resume_point(
    recorder: GradientStudy, binding: SpaceBinding, steps: int, final: str
) -> tuple[list[StepRecord], torch.Tensor | None]:
    """The steps a study holds and the ``u`` to restart from (None when it holds none).

    ``final="best"``: the stored point (step or last point) with the lowest loss; ``"last"``:
    the last point of the latest finished run when it ended after the last stored step, else
    the last stored step's point (a killed run: the update of that step is lost)."""
    stored = [step_from_trial(*t) for t in recorder.stored_steps()]
    done = stored[-1].step + 1 if stored else 0
    if done >= steps:
        raise ValueError(
            f"the study already holds {done} gradient steps; steps={steps} leaves nothing to resume. "
            f"Fix: ask for more steps (--steps > {done})."
        )
    last = recorder.stored_last()
    candidates: list[tuple[float, dict[str, float]]] = [(h.loss, h.point) for h in stored]
    if last is not None:
        candidates.append((float(last[2]["gradient"]["loss"]), last[0]))
    if not candidates:
        return stored, None
    if final == "best":
        finite = [c for c in candidates if math.isfinite(c[0])]
        point = min(finite, key=lambda c: c[0])[1] if finite else candidates[-1][1]
    elif last is not None and int(last[2]["gradient"]["step"]) == done:
        point = last[0]
    else:
        point = stored[-1].point
    values = torch.tensor([float(point[p]) for p in binding.space.names], dtype=torch.float64)
    return stored, binding.normalised(values).clamp(0.0, 1.0)


def optimize_psf(
    design: Design,
    space: DesignSpace,
    objective: str | PSFLoss = "axial_crb",
    *,
    steps: int = 20,
    optimizer: str = "adam",
    lr: float = 0.05,
    schedule: str = "constant",
    dtype: str = "float32",
    settings: EvaluationSettings | None = None,
    options: Mapping[str, Any] | None = None,
    constraints: Sequence[Constraint] | None = None,
    catalogue: FocalLengthCatalogue | None = None,
    check_float64: bool = True,
    tolerance: float = GRADIENT_TOLERANCE,
    study: str | None = None,
    study_name: str = "lfm_study",
    seed: int = 0,
    final: str = "best",
    resume: bool = False,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> GradientResult:
    """PSF engineering: descend a differentiable PSF objective (b) over ``space`` from ``design``.

    Parameters
    ----------
    design : a Fourier- or conventional-LFM design (the start; values outside the bounds are projected
        onto them).
    space : the free parameters (:data:`.gradient_params.DIFFERENTIABLE_PATHS`, for a conventional LFM
        :data:`.gradient_params.CONVENTIONAL_PATHS`; others are refused
        with :class:`.gradient_params.NotDifferentiableError`). Their bounds are the box projected on.
    objective : ``axial_crb`` (um, minimise), ``depth_dissimilarity`` (minimise), ``mtf_support``
        (soft, maximise), or a :class:`PSFLoss` with a differentiable loss.
    steps, optimizer, lr, schedule : the descent (see the module docstring); ``lr`` in units of
        each parameter's range.
    dtype : "float32" (default) or "float64" (the whole run in double).
    settings : depths, crop, device (``settings.dtype`` is replaced by ``dtype``; default
        :meth:`EvaluationSettings.for_design`: the PSF crop chosen for the design).
    options : objective options (``photons``, ``background`` for ``axial_crb``; ``softness``).
    constraints : checked after every step (default :func:`.constraints.default_constraints`);
        the design's own validation always applies.
    catalogue : focal lengths snapped to it at the end (value before and after reported).
    check_float64 : compare the start gradient in float32 and float64 (:class:`PrecisionCheck`).
    study, study_name : a database (URL or SQLite path) to record every step into; None: not recorded.
    seed : recorded with every trial (the PSF objectives are deterministic).
    final : "best" (default): the design returned (and snapped) is the best point evaluated, a
        step or the point after the last update; "last": the point after the last update. Both
        the best step and the last point are in the result and the study.
    resume : continue the stored study ``study_name`` (same design, space, objective, settings and
        seed; ``steps`` is the total, so rerunning a killed run's call finishes it). Stored steps
        are never evaluated or recorded again: the run continues at the next step number. The
        parameters ``u`` and the optimiser state (Adam's moments, L-BFGS' history) are not stored,
        so the optimiser restarts fresh from the stored best point (``final="best"``) or the last
        one (``final="last"``: the last point of a finished run, else the last stored step's point),
        and the schedule continues at the global step. Without ``resume`` an existing study is refused.
    progress, cancel : as everywhere in the engine.
    """
    check_dtype(dtype)
    if final not in FINALS:
        raise ValueError(f"final must be one of {FINALS}; got {final!r}.")
    if resume and study is None:
        raise ValueError("resume=True needs a study to continue. Fix: give study (--study) and study_name.")
    built = psf_objective(objective, options)
    start = prepare_start(design, space, constraints)
    binding, u0 = start.binding, start.u
    base = settings or EvaluationSettings.for_design(design)
    direction = sign(built.direction)

    def loss_of(values: torch.Tensor, at: Design, precision: str) -> torch.Tensor:
        stack = binding.psf_stack(at, values, replace(base, dtype=precision))
        return direction * built.loss(stack).to(torch.float64)

    recorder = open_recorder(
        study, study_name, design=design, space=space,
        objective={"name": built.name, "unit": built.unit, "direction": built.direction},
        run_settings=replace(base, dtype=dtype),
        options={"optimizer": optimizer, "lr": lr, "schedule": schedule, "steps": steps}, seed=seed, resume=resume,
        objective_options=score_options(built),
    )  # fmt: skip
    stored: list[StepRecord] = []
    if recorder is not None and resume:
        stored, restart = resume_point(recorder, binding, steps, final)
        if restart is not None:
            u0 = restart
    check = None
    if check_float64:

        def fresh(precision: str) -> tuple[torch.Tensor, list[torch.Tensor]]:
            leaf = u0.clone().requires_grad_(True)
            return loss_of(binding.values(leaf), design, precision), [leaf]

        # the descent's first gradient is the start gradient in ``dtype`` (same point, same leaf)
        check = StartGradientCheck(fresh, dtype, tolerance, reuse=True)
    u = u0.clone().requires_grad_(True)
    first = stored[-1].step + 1 if stored else 0
    setup = DescentSetup(
        binding, design, steps, optimizer, lr, schedule, start.constraints,
        study=recorder, progress=progress, cancel=cancel, direction=built.direction, first_step=first,
        on_first_gradient=None if check is None else check.take,
    )  # fmt: skip
    history = stored + descend(setup, u, lambda x, _step: loss_of(binding.values(x), design, dtype))
    last_values, last_point = binding.values_and_point(u)
    with torch.no_grad():
        last_loss = float(loss_of(last_values, design, dtype))
    if recorder is not None:
        record_point(
            recorder, binding, design, last_point, last_loss * direction, seconds=0.0,
            gradient={"step": steps, "last": True, "loss": last_loss, "grad_norm": None, "lr": None,
                      "optimizer": optimizer, "backtracks": 0, "backtrack_reason": None},
        )  # fmt: skip
    chosen_point, chosen_loss = last_point, last_loss
    if final == "best":
        best = min((h for h in history if math.isfinite(h.loss)), key=lambda h: h.loss, default=None)
        if best is not None and best.loss < last_loss:
            chosen_point, chosen_loss = best.point, best.loss
    chosen, notes = design_at(binding, design, chosen_point)
    result = GradientResult(
        chosen, start.design, history, history[0].value, chosen_loss * direction,
        check=None if check is None else check.result(), final=final, final_point=chosen_point,
        last_value=last_loss * direction, last_point=last_point, resumed_from=len(stored),
    )  # fmt: skip
    result.warnings = notes

    def snapped_value(values: torch.Tensor, snapped: Design) -> float:
        with torch.no_grad():
            return float(loss_of(values, snapped, dtype)) * direction

    snap_result(result, binding, catalogue, snapped_value)
    return finish_study(result, recorder)
