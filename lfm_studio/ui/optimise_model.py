"""What the studio's "Optimise" dock runs, without Qt: freeable fields, the run, one row per candidate.

:func:`freeable_fields` lists the design values the dock can free: the parameter panel's
numeric fields (:data:`~lfm_studio.ui.parameter_fields.FIELDS`, single numbers of the
design's kind), the MLA's (every lenslet's focal length together with ``*``, one
lenslet's focal length or centre by index, or a regular array's numeric fields) and the
Zernike coefficients a design's ``pupil_phase`` lists (Fourier: any term; conventional: m = 0).
:class:`OptimiseRequest` is a whole run (free parameters with low/high/points, objective
names from :func:`~lfm_studio.engine.optimize.objective_names`, sampler, budget, optional
study file); :func:`run_optimisation` runs it through
:func:`~lfm_studio.engine.optimize.study.run_study` (a temporary SQLite study when no
file is given, so grid, TPE and random runs record and report candidates the same way)
and hands each stored candidate to ``on_row`` as a :class:`CandidateRow`.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.design_io import design_from_json
from lfm_studio.engine.design.space import unit_of
from lfm_studio.engine.optimize import DesignSpace, EvaluationSettings, Evaluator, Parameter, objective_named
from lfm_studio.engine.optimize.objectives import sign
from lfm_studio.engine.optimize.study import record_of, run_study
from lfm_studio.engine.performance import compute_design_metrics
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.simulation import simulate_psf
from lfm_studio.engine.systems.kinds import kind_of
from lfm_studio.ui.edits import read_path
from lfm_studio.ui.parameter_fields import FIELDS

SAMPLERS: tuple[str, ...] = ("grid", "tpe", "random")
"""Samplers the dock offers (``grid`` tries every grid point in order, up to the budget)."""

DEFAULT_CROP = 128  # camera pixels kept about the axis when an objective needs a PSF (fast candidates)
_MLA_ARRAY_FIELDS = (
    ("pitch_um", "MLA pitch"),
    ("aperture_diameter_um", "Lenslet aperture"),
    ("focal_length_mm", "Lenslet focal length"),
)


@dataclass(frozen=True)
class FreeableField:
    """A design value the dock can free: its path (as in a design space), label, unit and current value."""

    path: str
    label: str
    unit: str
    value: float


def _numeric(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def freeable_fields(design: Design) -> tuple[FreeableField, ...]:
    """The numeric design values the dock offers to free, panel fields first, then the MLA's."""
    out: list[FreeableField] = []
    for spec in FIELDS:
        if spec.parts != 1 or kind_of(design) not in spec.kinds:
            continue
        try:
            value = read_path(design, spec.path)
        except (AttributeError, KeyError, IndexError, TypeError):
            continue
        if _numeric(value):
            out.append(FreeableField(spec.path, spec.label, spec.unit, float(value)))
    mla = design.mla.model_dump(mode="json")
    lenslets = mla.get("lenslets") or []
    if lenslets:
        first = lenslets[0]["focal_length_mm"]
        out.append(
            FreeableField("mla.lenslets[*].focal_length_mm", "All lenslets: focal length", "mm", first)
        )
        for i, lens in enumerate(lenslets):
            out.append(
                FreeableField(f"mla.lenslets[{i}].focal_length_mm", f"Lenslet {i}: focal length", "mm",
                              float(lens["focal_length_mm"]))
            )  # fmt: skip
            for axis, name in ((0, "x"), (1, "y")):
                out.append(
                    FreeableField(f"mla.lenslets[{i}].center_um[{axis}]", f"Lenslet {i}: centre {name}", "µm",
                                  float(lens["center_um"][axis]))
                )  # fmt: skip
    for key, label in _MLA_ARRAY_FIELDS:
        if _numeric(mla.get(key)):
            out.append(FreeableField(f"mla.{key}", label, unit_of(key).replace("um", "µm"), float(mla[key])))
    if design.pupil_phase is not None:  # the Zernike terms the design lists (its pupil phase mask)
        for j, waves in design.pupil_phase.terms:
            out.append(
                FreeableField(f"pupil_phase.zernike_waves.{j}", f"Pupil phase: Zernike {j}", "waves", waves)
            )
    return tuple(out)


@dataclass(frozen=True)
class FreeParameter:
    """One freed value: ``points`` evenly spaced values from ``low`` to ``high`` (design-field units)."""

    path: str
    low: float
    high: float
    points: int = 3

    def to_parameter(self) -> Parameter:
        return Parameter(self.path, low=float(self.low), high=float(self.high), points=int(self.points))


@dataclass(frozen=True)
class OptimiseRequest:
    """One run of the dock.

    Attributes
    ----------
    parameters : the freed values (at least one).
    objectives : registered objective names; the first ranks the candidates.
    sampler : one of :data:`SAMPLERS`.
    budget : number of candidates (the grid is cut to its first ``budget`` points).
    study : SQLite file to store the study in (None: a temporary one, deleted after the run).
    resume : continue the study stored in ``study``.
    crop : camera pixels kept about the axis for objectives that need a PSF.
    objective_options : options for :func:`objective_named` (task settings).
    """

    parameters: tuple[FreeParameter, ...]
    objectives: tuple[str, ...]
    sampler: str = "grid"
    budget: int = 4
    study: str | None = None
    resume: bool = False
    crop: int | None = DEFAULT_CROP
    objective_options: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.parameters:
            raise ValueError("no parameter is freed. Fix: tick at least one parameter to optimise.")
        if not self.objectives:
            raise ValueError("no objective is chosen. Fix: tick at least one objective.")
        if self.sampler not in SAMPLERS:
            raise ValueError(f"sampler must be one of {SAMPLERS}; got {self.sampler!r}.")
        if not (isinstance(self.budget, int) and self.budget >= 1):
            raise ValueError(f"budget must be a whole number of candidates >= 1; got {self.budget!r}.")
        if self.resume and not self.study:
            raise ValueError("resume needs a study file. Fix: choose the study file to continue.")

    def space(self) -> DesignSpace:
        return DesignSpace(tuple(p.to_parameter() for p in self.parameters))


@dataclass(frozen=True)
class CandidateRow:
    """One stored candidate: trial number, parameters, objective values, feasibility, design JSON."""

    number: int
    params: dict[str, Any]
    values: dict[str, float] | None
    reason: str | None
    message: str
    design_json: str | None

    @property
    def feasible(self) -> bool:
        return self.values is not None

    def design(self) -> Design:
        """The candidate's design (refused for an infeasible candidate, which has none)."""
        if self.design_json is None:
            raise ValueError(
                f"candidate {self.number} is infeasible ({self.reason}): it has no design to load."
            )
        return design_from_json(self.design_json, origin=f"candidate {self.number}")


def row_of(trial: Any, names: Sequence[str]) -> CandidateRow:
    """A :class:`CandidateRow` from a stored Optuna trial of a study with objectives ``names``."""
    record = record_of(trial)
    values = None
    if trial.state.name == "COMPLETE":
        values = dict(zip(names, (float(v) for v in trial.values), strict=True))
    return CandidateRow(
        number=int(trial.number),
        params=dict(trial.params),
        values=values,
        reason=record.get("infeasible_reason"),
        message=record.get("infeasible_message") or "",
        design_json=record.get("design_json"),
    )


def best_so_far(rows: Sequence[CandidateRow], name: str, direction: str) -> list[float | None]:
    """The best feasible value of objective ``name`` after each row (None before the first feasible one)."""
    s, best, out = sign(direction), None, []
    for row in rows:
        if row.values is not None:
            v = row.values[name]
            if best is None or s * v < s * best:
                best = v
        out.append(best)
    return out


def best_row(rows: Sequence[CandidateRow], name: str, direction: str) -> CandidateRow | None:
    """The feasible row with the best value of ``name`` (first one on ties)."""
    feasible = [r for r in rows if r.values is not None]
    if not feasible:
        return None
    s = sign(direction)
    return min(feasible, key=lambda r: s * r.values[name])  # type: ignore[index]


def run_optimisation(
    base: Design,
    request: OptimiseRequest,
    *,
    on_row: Callable[[CandidateRow], None] | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> list[CandidateRow]:
    """Run ``request`` from ``base``; returns every stored candidate (resumed ones too) in trial order."""
    objectives = [objective_named(n, request.objective_options) for n in request.objectives]
    evaluator = Evaluator(
        base, request.space(), objectives, settings=EvaluationSettings(crop=request.crop)
    )  # raises ValueError naming a path the design does not have
    names = [o.name for o in objectives]
    rows: dict[int, CandidateRow] = {}

    def record(study: Any, trial: Any, _record: Any) -> None:
        row = row_of(trial, names)
        rows[row.number] = row
        if on_row is not None:
            on_row(row)

    scratch = None if request.study else Path(tempfile.mkdtemp(prefix="lfm_optimise_"))
    storage = str(scratch / "study.db") if scratch is not None else str(Path(request.study).expanduser())
    try:
        study = run_study(
            evaluator, storage, sampler=request.sampler, n_trials=request.budget, resume=request.resume,
            callbacks=(record,), progress=progress, cancel=cancel,
        )  # fmt: skip
        for trial in study.get_trials(deepcopy=False):  # earlier runs of a resumed study
            if trial.number not in rows and (trial.state.name == "COMPLETE" or record_of(trial)):
                rows[trial.number] = row_of(trial, names)
    finally:
        if scratch is not None:
            study = None
            shutil.rmtree(scratch, ignore_errors=True)
    return [rows[k] for k in sorted(rows)]


# Closed-form metrics shown side by side: (attribute, label, unit; lengths are shown in µm).
COMPARED_METRICS: tuple[tuple[str, str, str], ...] = (
    ("lateral_resolution", "Lateral resolution", "µm"),
    ("axial_resolution", "Axial resolution", "µm"),
    ("depth_of_field", "Depth of field", "µm"),
    ("field_of_view", "Field of view", "µm"),
    ("number_of_views", "Number of views", ""),
    ("effective_numerical_aperture", "Effective NA (one view)", ""),
    ("magnification", "Magnification", "×"),
)


_SYMBOLS = {">=": "≥", "<=": "≤"}


def _shown(value: Any, unit: str) -> str:
    if value is None:
        return "n/a"
    scaled = value / 1e-6 if unit == "µm" else value
    return f"{scaled:.4g} {unit}".rstrip()


def comparison_rows(a: Design, b: Design) -> list[tuple[str, str, str]]:
    """``(quantity, A, B)`` text rows: the closed-form metrics, then each requirement check of A and B."""
    metrics_a, metrics_b = compute_design_metrics(a), compute_design_metrics(b)
    rows = [
        (
            label,
            _shown(getattr(metrics_a.closed_form, attr), unit),
            _shown(getattr(metrics_b.closed_form, attr), unit),
        )
        for attr, label, unit in COMPARED_METRICS
    ]
    verdict = {True: "PASS", False: "FAIL", None: "?"}
    for check_a, check_b in zip(metrics_a.requirements, metrics_b.requirements, strict=True):
        unit = "µm" if check_a.unit == "um" else check_a.unit
        limit = _shown(check_a.limit, unit)
        rows.append(
            (
                f"Requirement: {check_a.quantity.replace('_', ' ')} {_SYMBOLS.get(check_a.comparison, check_a.comparison)} {limit}",
                f"{verdict[check_a.passed]} ({_shown(check_a.value, unit)})",
                f"{verdict[check_b.passed]} ({_shown(check_b.value, unit)})",
            )
        )
    met = {True: "meets all", False: "fails some", None: "undecided"}
    rows.append(("Requirements overall", met[metrics_a.requirements_met], met[metrics_b.requirements_met]))
    return rows


PREVIEW_CROP = 512  # camera pixels kept about the axis in the Compare tab's PSF preview


def psf_preview(design: Design, *, crop: int = PREVIEW_CROP, cancel: CancelToken = None) -> Any:
    """A quick look at ``design``'s PSF at the native focal plane (depth 0): a 2-D numpy array.

    Fourier designs: the sensor image of a point on the axis, the central ``crop`` x ``crop``
    pixels, square-rooted (so dim views show) and scaled to a peak of 1. Conventional designs:
    the pattern behind the central lenslet for the on-axis source.
    """
    stack = simulate_psf(design, depths=(0.0,), crop=crop, cancel=cancel)
    data = stack.data.detach().cpu().double()
    if data.ndim == 5:  # conventional (S, S, Z, H, H): the central source position
        data = data[data.shape[0] // 2, data.shape[1] // 2]
    image = data[0].clamp(min=0).sqrt()
    peak = float(image.max())
    return (image / peak if peak > 0 else image).numpy()
