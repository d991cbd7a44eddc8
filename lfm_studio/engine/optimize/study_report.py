"""Read a stored study back: one row per trial, the best candidates, the Pareto front, as text.

Used by ``lfm-studio study show`` and the studio; values keep the units the study stored
with its objectives.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from lfm_studio.engine.optimize.study import record_of


@dataclass(frozen=True)
class TrialRow:
    """One trial: ``state`` is "complete", "infeasible", "interrupted" or Optuna's state name."""

    number: int
    state: str
    params: dict[str, Any]
    values: tuple[float, ...] | None
    reason: str | None
    seconds: float | None
    reused_from: int | None


def objectives_of(study: Any) -> list[dict[str, str]]:
    """``[{name, unit, direction}]`` as stored with the study."""
    return list(study.user_attrs.get("objectives", []))


def trial_rows(study: Any) -> list[TrialRow]:
    rows = []
    for t in study.get_trials(deepcopy=False):
        record = record_of(t)
        reason = record.get("infeasible_reason")
        if t.state.name == "COMPLETE":
            state = "complete"
        elif t.state.name == "FAIL":
            state = "infeasible" if reason is not None else "interrupted"
        else:
            state = t.state.name.lower()
        timing = record.get("timing") or {}
        rows.append(
            TrialRow(
                t.number,
                state,
                dict(t.params),
                tuple(t.values) if t.state.name == "COMPLETE" else None,
                reason,
                timing.get("total_s"),
                record.get("reused_from"),
            )
        )
    return rows


def pareto_front(study: Any) -> list[Any]:
    """The best trials: the Pareto front for several objectives, the best one for one (empty if none complete)."""
    complete = [t for t in study.get_trials(deepcopy=False) if t.state.name == "COMPLETE"]
    if not complete:
        return []
    if len(study.directions) == 1:
        return [study.best_trial]
    return sorted(study.best_trials, key=lambda t: t.number)


def _num(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else str(value)
    return str(value)


def format_table(study: Any, *, limit: int | None = None) -> str:
    """The trials as a text table (parameters, objective values with units, state, reason, seconds)."""
    objectives = objectives_of(study)
    rows = trial_rows(study)
    params = list(dict.fromkeys(k for r in rows for k in r.params))
    heads = ["#", *params, *(f"{o['name']} [{o['unit'] or '-'}] ({o['direction'][:3]})" for o in objectives)]
    heads += ["state", "s", "note"]
    body = []
    for r in rows if limit is None else rows[-limit:]:
        values = list(r.values) if r.values is not None else ["-"] * len(objectives)
        note = r.reason or ("" if r.reused_from is None else f"= #{r.reused_from}")
        seconds = "-" if r.seconds is None else f"{r.seconds:.2f}"
        body.append(
            [
                str(r.number),
                *(_num(r.params.get(p, "-")) for p in params),
                *map(_num, values),
                r.state,
                seconds,
                note,
            ]
        )
    widths = [max(len(h), *(len(b[i]) for b in body)) if body else len(h) for i, h in enumerate(heads)]
    lines = ["  ".join(h.ljust(w) for h, w in zip(heads, widths, strict=True))]
    lines += ["  ".join(c.ljust(w) for c, w in zip(b, widths, strict=True)) for b in body]
    return "\n".join(lines)


def format_front(study: Any) -> str:
    """The best trial (one objective) or the Pareto front (several), one line each."""
    objectives = objectives_of(study)
    front = pareto_front(study)
    if not front:
        return "no feasible candidate yet."
    title = "best candidate" if len(objectives) == 1 else f"Pareto front ({len(front)} candidates)"
    lines = [f"{title}:"]
    for t in front:
        values = ", ".join(
            f"{o['name']} {_num(v)}{' ' + o['unit'] if o['unit'] else ''}"
            for o, v in zip(objectives, t.values, strict=True)
        )
        params = ", ".join(f"{k}={_num(v)}" for k, v in t.params.items())
        lines.append(f"  #{t.number}: {values}  <- {params}")
    return "\n".join(lines)


def summary(study: Any) -> dict[str, int]:
    """Counts of trials by state (complete, infeasible, interrupted...) and by infeasible reason."""
    counts: dict[str, int] = {}
    for r in trial_rows(study):
        counts[r.state] = counts.get(r.state, 0) + 1
        if r.reason:
            counts[f"infeasible: {r.reason}"] = counts.get(f"infeasible: {r.reason}", 0) + 1
    return counts


@dataclass(frozen=True)
class Insensitive:
    """A parameter that never changed an objective: ``groups`` sets of complete trials equal in every
    other parameter and differing in this one all had the same ``value`` of ``objective`` (each
    group its own value; ``value`` is the first group's)."""

    parameter: str
    objective: str
    groups: int
    value: float


def insensitive_parameters(study: Any, *, rtol: float = 1e-6) -> list[Insensitive]:
    """Parameters of ``study`` that changed none of the values of an objective.

    For each parameter and objective: the complete trials are grouped by the values of every other
    parameter; in each group with at least two values of the parameter, the objective's values must
    agree to ``rtol`` (relative to the largest magnitude; all-zero values agree). Listed when
    at least one such group exists and every such group agrees: in this space the objective does
    not see the parameter (e.g. the NA of a Fourier design whose lenslet apertures all lie inside
    the relayed pupil: they, not the NA, stop the light). Empty when no group varies one parameter
    alone (a random sampler rarely makes such pairs).
    """
    complete = [t for t in study.get_trials(deepcopy=False) if t.state.name == "COMPLETE"]
    names = [o["name"] for o in objectives_of(study)] or [
        f"objective {i}" for i in range(len(study.directions))
    ]
    params = sorted({p for t in complete for p in t.params})
    found = []
    for param in params:
        groups: dict[str, list[Any]] = {}
        for t in complete:
            others = {k: v for k, v in t.params.items() if k != param}
            groups.setdefault(repr(sorted(others.items())), []).append(t)
        varied = [g for g in groups.values() if len({repr(t.params.get(param)) for t in g}) > 1]
        if not varied:
            continue
        for index, name in enumerate(names):
            if all(_agree([float(t.values[index]) for t in group], rtol) for group in varied):
                found.append(Insensitive(param, name, len(varied), float(varied[0][0].values[index])))
    return found


def _agree(values: list[float], rtol: float) -> bool:
    """All finite and equal to ``rtol`` of the largest magnitude (all-zero values agree)."""
    scale = max(abs(v) for v in values)
    return all(map(math.isfinite, values)) and max(values) - min(values) <= rtol * max(scale, 1e-300)
