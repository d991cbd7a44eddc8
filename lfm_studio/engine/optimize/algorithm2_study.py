"""Algorithm 2 recorded into a stored, resumable study (the same format as :func:`.study.run_study`).

Every layout Algorithm 2 considers becomes one Optuna trial:

- parameters ``size``, ``i``, ``j`` (the block tried, cells; ``i = j = -1`` for the initial
  all-minimum layout) and ``base`` (``initial`` / ``current`` / ``last``: the layout it was
  merged into); the resulting layout, a JSON block list ``[[i, j, size], ...]``, is
  ``record["layout"]`` (Optuna parameters need one fixed distribution per name, so a
  layout string cannot be a categorical parameter of its own);
- the objective value (one objective: Algorithm 2 is a greedy search on one score; fold
  several with :class:`~.objectives.WeightedSum`);
- user attribute ``record`` in the :meth:`~.evaluate.EvaluationRecord.attrs` format
  (``values``, ``infeasible_reason`` / ``infeasible_message``, ``timing``, ``design_json``,
  ``seed``, ``warnings``, ``cache``) plus ``algorithm2``: the step (``index``, ``size``,
  ``i``, ``j``, ``base``, ``accepted``). Infeasible layouts are ``FAIL`` trials with their
  reason (``layout_refused`` for a block outside the pupil or a conflict, ``invalid_design``
  or a constraint code for a layout the design checks refuse, ``evaluation_refused`` for an
  objective that refused it).

The study's attributes name the search (``space = {"algorithm2": {...}}``, the objective,
the settings, the base design); resuming checks they match. Trials are written whole
(one ``add_trial`` after the layout is scored), so a killed run leaves no half trial, and a
resumed run replays the deterministic search taking every stored layout's score from the
study (:func:`.algorithm2.algorithm2`'s ``lookup``): no stored layout is scored again.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.design_io import design_to_json
from lfm_studio.engine.optimize.algorithm2 import Algorithm2Result, LayoutTrial, algorithm2
from lfm_studio.engine.optimize.candidate import EvaluationSettings
from lfm_studio.engine.optimize.constraints import (
    Constraint,
    Infeasible,
    default_constraints,
    first_violation,
)
from lfm_studio.engine.optimize.evaluate import score_design
from lfm_studio.engine.optimize.mla_cells import Block, MLAPlane, check_symmetry
from lfm_studio.engine.optimize.objectives import Objective
from lfm_studio.engine.optimize.study import (
    DEFAULT_STUDY_NAME,
    RECORD,
    objective_attrs,
    objective_options,
    open_stored,
    record_of,
    require_optuna,
    study_description,
)
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.systems.lenslet_cache import LensletCache

BASES: tuple[str, ...] = ("initial", "current", "last")


def layout_key(blocks: Iterable[Block]) -> str:
    """The layout as the stored JSON string ``[[i, j, size], ...]`` (the order Algorithm 2 keeps)."""
    return json.dumps([[b.i, b.j, b.size] for b in blocks])


def layout_blocks(key: str) -> tuple[Block, ...]:
    """The blocks of a stored layout string (inverse of :func:`layout_key`)."""
    return tuple(Block(int(i), int(j), int(size)) for i, j, size in json.loads(key))


class _StepScorer:
    """Scores a layout's design for Algorithm 2 and keeps the full record for the study."""

    def __init__(
        self,
        objective: Objective,
        settings: EvaluationSettings,
        constraints: Sequence[Constraint],
        seed: int,
    ) -> None:
        self.objective, self.settings, self.constraints, self.seed = objective, settings, constraints, seed
        self.cache = LensletCache(device=settings.device)
        self.pending: dict[str, Any] | None = None  # what the last call found, taken by the recorder

    def __call__(self, design: Design) -> float:
        before = self.cache.counters()
        found = first_violation(design, self.constraints)
        values: dict[str, float] | None = None
        timing: dict[str, float] = {}
        if found is None:
            values, found, timing = score_design(
                design, (self.objective,), self.settings, seed=self.seed, cache=self.cache
            )
        self.pending = {
            "values": values,
            "infeasible": found,
            "timing": timing,
            "design_json": design_to_json(design),
            "cache": self.cache.use_since(before),
        }
        if found is not None:
            raise ValueError(str(found))  # Algorithm 2 records it as infeasible, with this reason
        assert values is not None
        return values[self.objective.name]


def _reason_code(step: LayoutTrial, found: Infeasible | None) -> tuple[str, str] | tuple[None, None]:
    if not step.reason:
        return None, None
    if found is not None:
        return found.reason, found.message
    code = "layout_refused" if not step.blocks else "invalid_design"
    return code, step.reason


def run_algorithm2_study(
    design: Design,
    objective: Objective,
    storage: str,
    *,
    min_lenslet_um: float,
    symmetry: str = "none",
    sizes: Iterable[int] | None = None,
    study_name: str = DEFAULT_STUDY_NAME,
    resume: bool = False,
    settings: EvaluationSettings | None = None,
    constraints: Sequence[Constraint] | None = None,
    seed: int = 0,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    on_step: Callable[[LayoutTrial, dict[str, Any]], None] | None = None,
) -> tuple[Algorithm2Result, Any]:
    """Run (or resume) Algorithm 2 on ``design`` recording every layout into a stored study.

    Parameters
    ----------
    design : the design whose MLA is searched.
    objective : the score (its ``direction`` is Algorithm 2's).
    storage : database URL or SQLite file path (as :func:`.study.run_study`).
    min_lenslet_um : minimum lenslet size ``d_min``, micrometres (the cell of the grid).
    symmetry, sizes : as :func:`.algorithm2.algorithm2`.
    study_name, resume : as :func:`.study.run_study` (a resumed study must be the same search).
    settings : how candidates are simulated (default :meth:`EvaluationSettings.for_design`: the PSF
        crop chosen for the design).
    constraints : checks of each layout's design (default: the Fourier-design checks).
    seed : recorded with every trial.
    progress, cancel : as :func:`.algorithm2.algorithm2`.
    on_step : called with each step (:class:`.algorithm2.LayoutTrial`) and its stored record
        (the ``record`` user attribute, ``design_json`` included) right after the trial is
        stored, in the worker that runs the search (the studio's Optimise dock shows each
        layout as it is scored). Steps a resumed study already holds are not passed.

    Returns
    -------
    ``(Algorithm2Result, optuna.Study)``
    """
    optuna = require_optuna()
    plane = MLAPlane.from_design(design, float(min_lenslet_um))
    check_symmetry(symmetry)
    settings = settings or EvaluationSettings.for_design(design)
    if constraints is None:
        constraints = default_constraints(design)
    order = None if sizes is None else list(sizes)
    space = {
        "algorithm2": {
            "min_lenslet_um": float(min_lenslet_um),
            "cells": plane.cells,
            "symmetry": symmetry,
            "sizes": order,
        }
    }
    attrs = study_description(
        design, space, [objective_attrs(objective)], settings.to_dict(), "algorithm2", seed,
        objective_options([objective]),
    )  # fmt: skip
    study = open_stored(attrs, [objective.direction], storage, study_name=study_name, resume=resume)
    stored_steps: set[int] = set()
    by_layout: dict[str, tuple[float | None, str]] = {}
    for trial in study.get_trials(deepcopy=False):
        stored = record_of(trial)
        step = stored.get("algorithm2")
        if step is None or trial.state.name not in ("COMPLETE", "FAIL"):
            continue
        stored_steps.add(int(step["index"]))
        key = stored.get("layout", "[]")
        if key != "[]":
            value = float(trial.values[0]) if trial.state.name == "COMPLETE" else None
            by_layout[key] = (value, stored.get("infeasible_message") or "")

    def lookup(blocks: tuple[Block, ...]) -> tuple[float | None, str] | None:
        return by_layout.get(layout_key(blocks))

    scorer = _StepScorer(objective, settings, tuple(constraints), seed)
    dist = optuna.distributions
    cells = plane.cells
    distributions = {
        "size": dist.IntDistribution(1, cells),
        "i": dist.IntDistribution(-1, cells),
        "j": dist.IntDistribution(-1, cells),
        "base": dist.CategoricalDistribution(BASES),
    }

    def record(step: LayoutTrial) -> None:
        pending, scorer.pending = scorer.pending, None
        if step.index in stored_steps:
            return
        found = None if pending is None else pending["infeasible"]
        reason, message = _reason_code(step, found)
        values = None if step.score is None else {objective.name: step.score}
        key = layout_key(step.blocks)
        attrs = {
            "values": values,
            "infeasible_reason": reason,
            "infeasible_message": message,
            "timing": {**(pending or {}).get("timing", {}), "total_s": step.seconds},
            "design_json": (pending or {}).get("design_json"),
            "seed": seed,
            "warnings": list(step.warnings),
            "cache": (pending or {}).get("cache", {}),
            "layout": key,
            "algorithm2": {"index": step.index, **step.params, "accepted": step.accepted},
        }
        if step.reused:
            attrs["reused"] = True
        trial = optuna.trial.create_trial(
            params={
                "size": step.params["size"],
                "i": -1 if step.params["i"] is None else step.params["i"],
                "j": -1 if step.params["j"] is None else step.params["j"],
                "base": step.params["base"],
            },
            distributions=distributions,
            values=None if values is None else [step.score],
            state=optuna.trial.TrialState.COMPLETE if values is not None else optuna.trial.TrialState.FAIL,
            user_attrs={RECORD: attrs},
        )
        study.add_trial(trial)
        stored_steps.add(step.index)
        if on_step is not None:
            on_step(step, attrs)

    result = algorithm2(
        design,
        scorer,
        plane=plane,
        sizes=order,
        symmetry=symmetry,
        direction=objective.direction,
        progress=progress,
        cancel=cancel,
        record=record,
        lookup=lookup,
    )
    return result, study
