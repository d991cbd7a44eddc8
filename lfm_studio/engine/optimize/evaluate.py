"""Evaluate one point of a design space: build, repair, check, score; record everything.

:class:`Evaluator` turns a point into an :class:`EvaluationRecord`: the parameters, the
objective values (by objective name), the seconds per stage, the candidate's design JSON,
the seed, the design warnings, and for an infeasible point its :class:`Infeasible` reason
(nothing is scored then). It keeps one per-lenslet PSF cache across calls.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.design_io import design_to_json
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.design.space import DesignSpace, Point
from lfm_studio.engine.memory import MemoryBudgetError
from lfm_studio.engine.optimize.candidate import Candidate, EvaluationSettings
from lfm_studio.engine.optimize.constraints import (
    Constraint,
    FocalLengthCatalogue,
    Infeasible,
    default_constraints,
    first_violation,
    infeasible_from_error,
)
from lfm_studio.engine.optimize.objectives import Objective
from lfm_studio.engine.optimize.task_score import TaskFloorWarning
from lfm_studio.engine.systems.lenslet_cache import LensletCache


@dataclass
class EvaluationRecord:
    """What one evaluation found (stored with every trial of a study).

    values : objective name -> value in the objective's unit (None when infeasible).
    timing : seconds per stage (``psf_s``, ``simulate_s``, ``reconstruct_s``, ``score_s``,
        ``total_s`` and ``overhead_s`` = total minus the stages).
    cache : per-lenslet cache use (:meth:`LensletCache.use_since`): ``hits``, ``misses``, and
        when the cache could not hold this candidate's lenslets ``not_stored``, ``needed_bytes``
        and ``budget_bytes``.
    at_floor : names of the task objectives whose score did not beat the all-zero volume's by
        their margin (:class:`~.task_score.TaskFloorWarning`; its message is in ``warnings``).
    """

    params: Point
    values: dict[str, float] | None
    infeasible: Infeasible | None
    timing: dict[str, float]
    design_json: str | None
    seed: int
    warnings: tuple[str, ...] = ()
    cache: dict[str, int] = field(default_factory=dict)
    at_floor: tuple[str, ...] = ()

    @property
    def feasible(self) -> bool:
        return self.infeasible is None

    def attrs(self) -> dict[str, Any]:
        """JSON-ready user attributes of the trial."""
        return {
            "values": self.values,
            "infeasible_reason": None if self.infeasible is None else self.infeasible.reason,
            "infeasible_message": None if self.infeasible is None else self.infeasible.message,
            "timing": self.timing,
            "design_json": self.design_json,
            "seed": self.seed,
            "warnings": list(self.warnings),
            "cache": self.cache,
            "at_floor": list(self.at_floor),
        }


def score_design(
    design: Design,
    objectives: Sequence[Objective],
    settings: EvaluationSettings,
    *,
    seed: int = 0,
    cache: LensletCache | None = None,
) -> tuple[dict[str, float] | None, Infeasible | None, dict[str, float]]:
    """Score a built design: ``(values, None, timing)``, or ``(None, reason, timing)`` when an
    objective refused it with a ``ValueError`` (e.g. a rejected reconstruction).

    ``values`` maps objective names to values in their units; ``timing`` holds seconds per stage.
    """
    candidate = Candidate(design, settings, seed=seed, cache=cache)
    try:
        values = {o.name: float(o(candidate)) for o in objectives}
    except MemoryBudgetError:
        raise
    except ValueError as error:
        return None, Infeasible("evaluation_refused", str(error)), dict(candidate.timing)
    return values, None, dict(candidate.timing)


class Evaluator:
    """Scores points of ``space`` applied to ``base`` (picklable for Dask: the cache is rebuilt).

    Parameters
    ----------
    base : the starting design.
    space : the free parameters.
    objectives : what to score (names must be distinct).
    constraints : checks of a built design (default: inside the pupil, sub-images on the
        sensor and apart; Fourier designs only).
    catalogue : optional focal-length catalogue applied before the checks.
    settings : how candidates are simulated (default :meth:`EvaluationSettings.for_design` of ``base``:
        the PSF crop chosen for the design).
    seed : recorded with every trial (task scores use their own held-out seeds).
    cache_bytes : budget of the per-lenslet cache (default: a quarter of the free memory of
        ``settings.device``, between 512 MiB and 8 GiB: :func:`default_cache_bytes`).
    """

    def __init__(
        self,
        base: Design,
        space: DesignSpace,
        objectives: Sequence[Objective],
        *,
        constraints: Sequence[Constraint] | None = None,
        catalogue: FocalLengthCatalogue | None = None,
        settings: EvaluationSettings | None = None,
        seed: int = 0,
        cache_bytes: int | None = None,
    ) -> None:
        names = [o.name for o in objectives]
        if not objectives or len(set(names)) != len(names):
            raise ValueError(f"objectives must be at least one, with distinct names; got {names}.")
        space.check_paths(base)
        self.base, self.space, self.objectives = base, space, tuple(objectives)
        if constraints is None:
            constraints = default_constraints(base)
        self.constraints = tuple(constraints)
        self.catalogue = catalogue
        self.settings = settings or EvaluationSettings.for_design(base)
        self.seed = seed
        self.cache_bytes = cache_bytes
        self.cache = LensletCache(cache_bytes, device=self.settings.device)
        self.evaluations = 0  # points scored (not counting infeasible ones)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["cache"] = None
        return state

    def __setstate__(self, state: Mapping[str, Any]) -> None:
        self.__dict__.update(state)
        self.cache = LensletCache(self.cache_bytes, device=self.settings.device)

    def build(self, point: Mapping[str, Any]) -> tuple[Design | None, Infeasible | None, tuple[str, ...]]:
        """``(design, None, warnings)`` or ``(None, reason, warnings)`` for ``point``."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", DesignWarning)
            try:
                design = self.space.apply(self.base, point)
                if self.catalogue is not None:
                    design = self.catalogue.snap(design)
            except ValueError as error:
                return None, infeasible_from_error(error), ()
            found = first_violation(design, self.constraints)
        notes = tuple(dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, DesignWarning)))
        return (None, found, notes) if found is not None else (design, None, notes)

    def __call__(self, point: Mapping[str, Any]) -> EvaluationRecord:
        start = time.perf_counter()
        design, infeasible, notes = self.build(point)
        values: dict[str, float] | None = None
        timing: dict[str, float] = {}
        before = self.cache.counters()
        at_floor: list[TaskFloorWarning] = []
        if design is not None:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", TaskFloorWarning)
                values, infeasible, timing = score_design(
                    design, self.objectives, self.settings, seed=self.seed, cache=self.cache
                )
            for w in caught:  # the floor warnings go into the record, the others on as they came
                if isinstance(w.message, TaskFloorWarning):
                    at_floor.append(w.message)
                else:
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno, source=w.source)
            self.evaluations += values is not None
            if values is not None:
                notes = (*notes, *dict.fromkeys(str(w) for w in at_floor))
        total = time.perf_counter() - start
        timing["total_s"] = total
        timing["overhead_s"] = max(0.0, total - sum(v for k, v in timing.items() if k not in ("total_s",)))
        return EvaluationRecord(
            params=dict(point),
            values=values,
            infeasible=infeasible,
            timing=timing,
            design_json=None if design is None else design_to_json(design),
            seed=self.seed,
            warnings=notes,
            cache=self.cache.use_since(before),
            at_floor=tuple(dict.fromkeys(w.objective for w in at_floor)) if values is not None else (),
        )
