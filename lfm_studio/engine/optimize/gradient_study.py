"""The gradient optimiser recorded into a stored study (the format of :func:`.study.run_study`).

Every step is one Optuna trial: the parameters are the design values of the point evaluated
at that step (before the update), the value is the objective there, and the ``record`` user
attribute holds, as for grid search and Algorithm 2, ``values``, ``timing`` (``total_s``:
seconds of the step, forward + backward + update), ``design_json`` (the design at that
point), ``seed``, and ``gradient``: the step number, the minimised loss, the gradient norm
(of the normalised parameters ``u``), the learning rate and any backtracking. The study's
``sampler`` attribute is ``gradient-adam`` / ``gradient-lbfgs`` and its ``gradient``
attribute holds the run summary (start / final / snapped values, the float32-float64 check).

The last point of a run (after its last update; evaluated, but not a step) is stored too, as
a trial whose ``gradient`` record has ``last: true`` and ``step`` = the steps done. A run on an
existing study name is refused unless ``resume=True``: then the study must have been made with
the same design, space, objective, settings and seed, and :meth:`GradientStudy.stored_steps` /
:meth:`GradientStudy.stored_last` give what it holds (see :func:`.gradient.optimize_psf`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.space import DesignSpace, Point
from lfm_studio.engine.optimize.constraints import Infeasible
from lfm_studio.engine.optimize.evaluate import EvaluationRecord
from lfm_studio.engine.optimize.study import (
    DEFAULT_STUDY_NAME,
    RECORD,
    open_stored,
    record_of,
    require_optuna,
    study_description,
)

EXISTS_FIX = "choose another --study-name or database, or continue a PSF run with resume=True (--resume)."
"""The refusal's fix for an existing study name (end-to-end runs cannot resume: :mod:`.end_to_end`)."""


def continuous_distributions(space: DesignSpace) -> dict[str, Any]:
    """One ``FloatDistribution(low, high)`` per parameter (design units): the descent moves every
    parameter continuously inside its bounds, so a space's ``log``, ``step`` or ``points`` (which
    :func:`.study.distributions` turns into stepped or categorical distributions) do not apply; a
    stepped distribution would refuse the off-grid points a descent visits."""
    optuna = require_optuna()
    return {
        p.path: optuna.distributions.FloatDistribution(float(p.low), float(p.high))  # type: ignore[arg-type]
        for p in space.parameters
    }


class GradientStudy:
    """Writes one trial per gradient step into a new stored study."""

    def __init__(
        self,
        storage: str,
        *,
        design: Design,
        space: DesignSpace,
        objective: Mapping[str, str],
        settings: Mapping[str, Any],
        sampler: str,
        seed: int,
        study_name: str = DEFAULT_STUDY_NAME,
        resume: bool = False,
        options: Mapping[str, Any] | None = None,
    ) -> None:
        """``options``: the objective's score options (:func:`.objectives.score_options`), compared on resume."""
        attrs = study_description(
            design,
            space.to_dict(),
            [objective],
            settings,
            sampler,
            seed,
            {objective["name"]: dict(options or {})},
        )
        self.study = open_stored(
            attrs,
            [objective["direction"]],
            storage,
            study_name=study_name,
            resume=resume,
            exists_fix=EXISTS_FIX,
        )
        self.objective = objective["name"]
        self.seed = seed
        self.space = space
        self._dists = continuous_distributions(space)

    def add(
        self,
        point: Mapping[str, float],
        value: float,
        design_json: str,
        *,
        seconds: float,
        gradient: Mapping[str, Any],
        warnings: Sequence[str] = (),
    ) -> None:
        """Store one step (a ``COMPLETE`` trial; a non-finite value is stored ``FAIL`` with reason ``not_finite``)."""
        optuna = require_optuna()
        params: Point = {
            p.path: min(max(float(point[p.path]), float(p.low)), float(p.high))  # type: ignore[arg-type]
            for p in self.space.parameters
        }
        finite = math.isfinite(value)
        evaluation = EvaluationRecord(
            params=params,
            values={self.objective: value} if finite else None,
            infeasible=None if finite else Infeasible("not_finite", f"the objective is {value}"),
            timing={"total_s": seconds},
            design_json=design_json,
            seed=self.seed,
            warnings=tuple(warnings),
        )
        record = {**evaluation.attrs(), "gradient": dict(gradient)}
        state = optuna.trial.TrialState.COMPLETE if finite else optuna.trial.TrialState.FAIL
        trial = optuna.trial.create_trial(
            params=params,
            distributions=self._dists,
            values=[value] if finite else None,
            state=state,
            user_attrs={RECORD: record},
        )
        self.study.add_trial(trial)

    def _gradient_trials(self) -> list[tuple[dict[str, float], float, dict[str, Any]]]:
        """``(params, value, record)`` of every stored gradient trial (value NaN for a failed one)."""
        out = []
        for trial in self.study.get_trials(deepcopy=False):
            record = record_of(trial)
            if "gradient" not in record or trial.state.name not in ("COMPLETE", "FAIL"):
                continue
            value = float(trial.values[0]) if trial.state.name == "COMPLETE" else math.nan
            out.append(({k: float(v) for k, v in trial.params.items()}, value, record))
        return out

    def stored_steps(self) -> list[tuple[dict[str, float], float, dict[str, Any]]]:
        """The stored steps (not the last points), ``(params, value, record)`` in step order."""
        steps = [t for t in self._gradient_trials() if not t[2]["gradient"].get("last")]
        return sorted(steps, key=lambda t: int(t[2]["gradient"]["step"]))

    def stored_last(self) -> tuple[dict[str, float], float, dict[str, Any]] | None:
        """The last point of the latest finished run (the one with the most steps), or None."""
        lasts = [t for t in self._gradient_trials() if t[2]["gradient"].get("last")]
        return max(lasts, key=lambda t: int(t[2]["gradient"]["step"])) if lasts else None

    def finish(self, summary: Mapping[str, Any]) -> None:
        """Store the run summary as the study attribute ``gradient``."""
        self.study.set_user_attr("gradient", dict(summary))
