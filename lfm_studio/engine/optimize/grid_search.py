"""Exhaustive grid search over a design space, in process (no database).

:func:`grid_search` evaluates every grid point of the space in order with one
:class:`~.evaluate.Evaluator` (so its per-lenslet PSF cache carries over: a point that moves
one lenslet recomputes that lenslet only) and returns every record with the best feasible
one. For stored, resumable searches and Optuna's samplers (grid, TPE, CMA-ES, random) use
:func:`~.study.run_study`, which evaluates points the same way.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from lfm_studio.engine.design.space import Point
from lfm_studio.engine.optimize.evaluate import EvaluationRecord, Evaluator
from lfm_studio.engine.optimize.objectives import Objective, sign
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint


@dataclass(frozen=True)
class SearchResult:
    """Every record of a search, in evaluation order, and the best feasible one (None if none)."""

    records: tuple[EvaluationRecord, ...]
    best: EvaluationRecord | None

    @property
    def infeasible(self) -> tuple[EvaluationRecord, ...]:
        return tuple(r for r in self.records if not r.feasible)


def best_of(records: Iterable[EvaluationRecord], objective: Objective) -> EvaluationRecord | None:
    """The feasible record with the best value of ``objective`` (first one on ties)."""
    feasible = [r for r in records if r.values is not None]
    if not feasible:
        return None
    s = sign(objective.direction)
    return min(feasible, key=lambda r: s * r.values[objective.name])  # type: ignore[index]


def grid_search(
    evaluator: Evaluator,
    points: Sequence[Point] | None = None,
    *,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> SearchResult:
    """Evaluate ``points`` (default: every grid point of ``evaluator.space``); best by the first objective."""
    todo = list(points) if points is not None else list(evaluator.space.grid())
    records = []
    for i, point in enumerate(todo):
        checkpoint(cancel, progress, i, len(todo), f"candidate {i + 1}/{len(todo)}")
        records.append(evaluator(point))
    checkpoint(cancel, progress, len(todo), len(todo), "done")
    return SearchResult(tuple(records), best_of(records, evaluator.objectives[0]))
