"""Objectives: what a candidate is scored on, each with a unit and a direction.

Every objective is a callable ``objective(candidate) -> float`` with ``name``, ``unit``
and ``direction`` ("minimize" or "maximize"). Kinds:

- (a) design requirements: :class:`ClosedForm` (one closed-form metric, e.g. the lateral
  resolution in um, minimised) and :class:`RequirementsPenalty` (how far a design falls
  short of a requirement set, default the larval zebrafish of thesis 2.3.1; closed form, or
  measured on the candidate's PSF), or :class:`RequirementsConstraint` to refuse designs
  that fail them;
- (b) PSF-engineering losses: :class:`PSFLoss` wraps any ``psf_loss(stack) -> tensor``
  (the losses of thesis 5.2.2 live in :mod:`.psf_losses`, registered by that module);
- (c) a task score: :class:`~.task_score.TaskScore` (held-out phantoms imaged and reconstructed).

Objectives compose: several at once are a multi-objective study (a Pareto front);
:class:`WeightedSum` folds several into one minimised number.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields, is_dataclass
from typing import Any, Literal, Protocol

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.errors import fmt
from lfm_studio.engine.optimize import psf_losses
from lfm_studio.engine.optimize.candidate import Candidate
from lfm_studio.engine.optimize.constraints import Infeasible
from lfm_studio.engine.performance import (
    ZEBRAFISH_LARVA,
    Requirement,
    closed_form_metrics,
    compute_design_metrics,
)

Direction = Literal["minimize", "maximize"]
DIRECTIONS: tuple[str, ...] = ("minimize", "maximize")


class Objective(Protocol):
    """A named score of a candidate, with its unit and whether lower or higher is better
    (read-only members, so frozen dataclasses implement it)."""

    @property
    def name(self) -> str: ...
    @property
    def unit(self) -> str: ...
    @property
    def direction(self) -> Direction: ...

    def __call__(self, candidate: Candidate) -> float: ...


def sign(direction: str) -> float:
    """+1 for "minimize", -1 for "maximize" (a value times the sign is a loss)."""
    if direction not in DIRECTIONS:
        raise ValueError(f"direction must be one of {DIRECTIONS}; got {direction!r}.")
    return 1.0 if direction == "minimize" else -1.0


# Closed-form metrics (engine/performance) an objective can name: quantity -> (unit, direction).
CLOSED_FORM_QUANTITIES: dict[str, tuple[str, Direction]] = {
    "lateral_resolution": ("um", "minimize"),
    "axial_resolution": ("um", "minimize"),
    "depth_of_field": ("um", "maximize"),
    "field_of_view": ("um", "maximize"),
    "number_of_views": ("", "maximize"),
    "effective_numerical_aperture": ("", "maximize"),
}


@dataclass(frozen=True)
class ClosedForm:
    """One closed-form metric of the design (:func:`closed_form_metrics`), in um for lengths."""

    quantity: str
    direction: Direction = "minimize"
    unit: str = "um"

    def __post_init__(self) -> None:
        if self.quantity not in CLOSED_FORM_QUANTITIES:
            raise ValueError(
                f"closed-form quantity must be one of {sorted(CLOSED_FORM_QUANTITIES)}; got {self.quantity!r}."
            )
        sign(self.direction)

    @property
    def name(self) -> str:
        return self.quantity

    def __call__(self, candidate: Candidate) -> float:
        value = getattr(closed_form_metrics(candidate.design), self.quantity)
        if value is None:
            return float("inf") * sign(self.direction)
        return float(value) * (1e6 if self.unit == "um" else 1.0)


def requirement_shortfall(checks: Any) -> float:
    """Sum over requirement checks of the relative shortfall ``max(0, -margin / limit)`` (0: all met;
    an undefined value counts 1)."""
    total = 0.0
    for check in checks:
        relative = check.relative_margin
        total += 1.0 if relative is None else max(0.0, -relative)
    return total


@dataclass(frozen=True)
class RequirementsPenalty:
    """Relative shortfall from ``requirements`` (unitless, minimised; 0 when every requirement is met).

    ``basis="closed_form"`` reads the closed forms; ``"measured"`` measures the candidate's PSF
    stack (lateral/axial two-point resolution, depth of field; :func:`compute_design_metrics`).
    """

    requirements: tuple[Requirement, ...] = ZEBRAFISH_LARVA
    basis: Literal["closed_form", "measured"] = "closed_form"
    unit: str = ""
    direction: Direction = "minimize"

    @property
    def name(self) -> str:
        return "requirements_penalty" if self.basis == "closed_form" else "measured_requirements_penalty"

    def __call__(self, candidate: Candidate) -> float:
        psf = candidate.stack if self.basis == "measured" else None
        metrics = compute_design_metrics(candidate.design, psf=psf, requirements=self.requirements)
        checks = [c for c in metrics.requirements if c.basis == self.basis]
        return requirement_shortfall(checks)


@dataclass(frozen=True)
class RequirementsConstraint:
    """A constraint: the design's closed forms meet every requirement in ``quantities`` (default all)."""

    requirements: tuple[Requirement, ...] = ZEBRAFISH_LARVA
    quantities: tuple[str, ...] | None = None
    name: str = "requirements"

    def check(self, design: Design) -> Infeasible | None:
        metrics = compute_design_metrics(design, requirements=self.requirements)
        failed = [
            f"{c.label} {'undefined' if c.value is None else fmt(c.value * 1e6)} um, needs {c.comparison} {fmt(c.limit * 1e6)} um"
            for c in metrics.requirements
            if c.basis == "closed_form"
            and c.passed is not True
            and (self.quantities is None or c.quantity in self.quantities)
        ]
        return Infeasible("requirement_failed", "; ".join(failed)) if failed else None


@dataclass(frozen=True)
class PSFLoss:
    """A PSF-engineering loss ``loss(stack) -> 0-d tensor`` (thesis 5.2.2) on the candidate's PSF stack."""

    name: str
    loss: Callable[[Any], torch.Tensor]
    unit: str = ""
    direction: Direction = "minimize"

    def score_options(self) -> dict[str, Any]:
        """The loss's settings (the fields of a dataclass loss, e.g. ``photons``, ``background``)."""
        if not is_dataclass(self.loss):
            return {}
        return {f.name: getattr(self.loss, f.name) for f in fields(self.loss)}

    def __call__(self, candidate: Candidate) -> float:
        with candidate.timed("psf_loss_s"):
            return float(torch.as_tensor(self.loss(candidate.stack)).detach())


@dataclass(frozen=True)
class WeightedSum:
    """``sum_i w_i s_i v_i`` (``s_i`` = +1 for minimised, -1 for maximised terms): one minimised number."""

    terms: tuple[tuple[Objective, float], ...]
    name: str = "weighted_sum"
    unit: str = ""
    direction: Direction = "minimize"

    def __call__(self, candidate: Candidate) -> float:
        return sum(w * sign(obj.direction) * obj(candidate) for obj, w in self.terms)

    def score_options(self) -> dict[str, Any]:
        """Each term's name, weight and options (:func:`score_options`)."""
        return {"terms": [{"name": o.name, "weight": w, "options": score_options(o)} for o, w in self.terms]}


def score_options(objective: Any) -> dict[str, Any]:
    """The options that change ``objective``'s values (photons, iterations, seeds...), JSON-ready.

    A study stores them and refuses a resume whose objectives were built with other options
    (:mod:`.study`): their scores could not be ranked together. An objective declares them with a
    ``score_options()`` method; one without it (a closed form) has none.
    """
    own = getattr(objective, "score_options", None)
    return json.loads(json.dumps(own() if callable(own) else {}))


ObjectiveFactory = Callable[[Mapping[str, Any]], Objective]
_REGISTRY: dict[str, tuple[ObjectiveFactory, str]] = {}


def register_objective(name: str, factory: ObjectiveFactory, description: str) -> None:
    """Make ``name`` usable by :func:`objective_named` (and ``lfm-studio optimize --objective``).

    ``factory(options)`` builds the objective; ``options`` are the task settings of the run
    (photons, method, iterations, seeds...; see :class:`~.task_score.TaskScore`).
    """
    _REGISTRY[name] = (factory, description)


def objective_names() -> dict[str, str]:
    """Registered objective names and what each is."""
    return {name: text for name, (_, text) in sorted(_REGISTRY.items())}


def objective_named(name: str, options: Mapping[str, Any] | None = None) -> Objective:
    """The registered objective ``name`` built with ``options``."""
    if name not in _REGISTRY:
        raise ValueError(
            f"objective must be one of {sorted(_REGISTRY)}; got {name!r}. Fix: see docs/optimize.md."
        )
    return _REGISTRY[name][0](options or {})


def _closed_form_factory(quantity: str, unit: str, direction: Direction) -> ObjectiveFactory:
    def build(options: Mapping[str, Any]) -> Objective:
        return ClosedForm(quantity, direction, unit)

    return build


def _penalty_factory(basis: Literal["closed_form", "measured"]) -> ObjectiveFactory:
    def build(options: Mapping[str, Any]) -> Objective:
        return RequirementsPenalty(basis=basis)

    return build


for _quantity, (_unit, _direction) in CLOSED_FORM_QUANTITIES.items():
    register_objective(
        _quantity,
        _closed_form_factory(_quantity, _unit, _direction),
        f"closed-form {_quantity.replace('_', ' ')} ({_unit or 'unitless'}, {_direction})",
    )
register_objective(
    "requirements_penalty",
    _penalty_factory("closed_form"),
    "relative shortfall from the zebrafish requirements, closed forms (unitless, minimize; 0 = all met)",
)
register_objective(
    "measured_requirements_penalty",
    _penalty_factory("measured"),
    "relative shortfall from the zebrafish requirements measured on the PSF (unitless, minimize)",
)


# (b) The PSF-engineering losses of thesis 5.2.2 (:mod:`.psf_losses`) as named objectives.
def stack_intensities(stack: Any) -> torch.Tensor:
    """The PSFs of a :class:`~lfm_studio.engine.psf_stack.PSFStack` as ``(N, Z, Y, X)``: one ``(Z, Y, X)``
    stack per lateral source position (``N = 1`` for a shift-invariant stack; a conventional
    LFM stores one per position behind a lenslet, the leading axes)."""
    data = torch.as_tensor(stack.data)
    return data.reshape(-1, *data.shape[-3:])


def _mean_over_positions(stack: Any, loss: Callable[[torch.Tensor], torch.Tensor]) -> torch.Tensor:
    """``loss`` of every source position's ``(Z, Y, X)`` stack, averaged over positions."""
    return torch.stack([loss(psf) for psf in stack_intensities(stack)]).mean()


CRB_PHOTONS = 1000.0
"""Default photons detected per emitter for ``axial_crb`` (CLI ``--photons``, the studio's Optimise dock):
a bright fluorophore or a small bead detected through a high-NA objective in one camera frame
(single-molecule work sees 10^2-10^4). It is per emitter, not per image: the task scores'
default (:data:`.task_score.TASK_PHOTONS`, 1e5 per image) spreads over many emitters."""

CRB_BACKGROUND = 1.0
"""Default background of ``axial_crb``, photons per pixel (Poisson)."""


@dataclass(frozen=True)
class AxialCRBLoss:
    """Mean over depths (and source positions) of the axial Cramer-Rao bound (:func:`.psf_losses.axial_crb`), um.

    ``photons`` detected per emitter, ``background`` photons per pixel (Poisson).
    """

    photons: float = CRB_PHOTONS
    background: float = CRB_BACKGROUND

    def __call__(self, stack: Any) -> torch.Tensor:
        depths = torch.as_tensor(stack.depths, dtype=torch.float64)
        return (
            _mean_over_positions(
                stack,
                lambda psf: psf_losses.axial_crb(
                    psf, depths, photons=self.photons, background=self.background
                ).mean(),
            )
            * 1e6
        )


@dataclass(frozen=True)
class DepthDissimilarityLoss:
    """Mean normalised cross-correlation of the slices of all depth pairs (:func:`.psf_losses.depth_dissimilarity`)."""

    def __call__(self, stack: Any) -> torch.Tensor:
        return _mean_over_positions(stack, lambda psf: psf_losses.depth_dissimilarity(psf, reduction="mean"))


@dataclass(frozen=True)
class MTFSupportLoss:
    """Mean over depths of the MTF support fraction (:func:`.psf_losses.mtf_support`), in ``[0, 1]``."""

    threshold: float = 0.1
    band: float = 0.5

    def __call__(self, stack: Any) -> torch.Tensor:
        return _mean_over_positions(
            stack, lambda psf: psf_losses.mtf_support(psf, threshold=self.threshold, band=self.band).mean()
        )


def _option(options: Mapping[str, Any], key: str, default: float) -> float:
    """``options[key]`` as a float, ``default`` when it is missing or None (not given)."""
    value = options.get(key)
    return default if value is None else float(value)


def _psf_loss_factory(name: str) -> ObjectiveFactory:
    def build(options: Mapping[str, Any]) -> Objective:
        if name == "axial_crb":
            photons = _option(options, "photons", CRB_PHOTONS)
            background = _option(options, "background", CRB_BACKGROUND)
            return PSFLoss(name, AxialCRBLoss(photons, background), "um", "minimize")
        if name == "depth_dissimilarity":
            return PSFLoss(name, DepthDissimilarityLoss(), "", "minimize")
        return PSFLoss(name, MTFSupportLoss(), "", "maximize")

    return build


PSF_LOSS_OBJECTIVES: dict[str, str] = {
    "axial_crb": "axial Cramer-Rao bound of a point emitter, mean over depths, Poisson noise at "
    f"options photons per emitter (default {CRB_PHOTONS:g}) and background (default {CRB_BACKGROUND:g} "
    "photon/pixel) (um, minimize)",
    "depth_dissimilarity": "mean normalised cross-correlation of the PSF slices of every depth pair "
    "(unitless in [0, 1], minimize)",
    "mtf_support": "fraction of the band up to Nyquist where the MTF exceeds 0.1, mean over depths "
    "(unitless in [0, 1], maximize)",
}
for _name, _text in PSF_LOSS_OBJECTIVES.items():
    register_objective(_name, _psf_loss_factory(_name), _text)
