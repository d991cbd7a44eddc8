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

The dock offers three methods (:data:`METHODS`): grid search / design study (the above),
the thesis' Algorithm 2 for the MLA layout (:class:`Algorithm2Request`,
:func:`run_algorithm2_layout` through :func:`~lfm_studio.engine.optimize.run_algorithm2_study`:
one row per layout considered, the best layout chosen) and gradient optimisation
(:class:`GradientRequest`, :func:`run_gradient` through
:func:`~lfm_studio.engine.optimize.optimize_psf` or
:func:`~lfm_studio.engine.optimize.end_to_end.optimize_end_to_end`: one row per step, then the
final design). Both return a :class:`RunResult` (rows, the row the engine chose, a summary line).
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.design_io import design_from_json, design_to_json
from lfm_studio.engine.design.space import unit_of
from lfm_studio.engine.optimize import (
    DesignSpace,
    EvaluationSettings,
    Evaluator,
    Parameter,
    objective_named,
    objective_names,
    optimize_psf,
    run_algorithm2_study,
)
from lfm_studio.engine.optimize.algorithm2 import LayoutTrial
from lfm_studio.engine.optimize.algorithm2_study import layout_key
from lfm_studio.engine.optimize.constraints import REASONS
from lfm_studio.engine.optimize.end_to_end import RECONSTRUCTIONS, optimize_end_to_end
from lfm_studio.engine.optimize.gradient import OPTIMIZERS, PSF_OBJECTIVES, SCHEDULES, psf_objective, quietly
from lfm_studio.engine.optimize.gradient_params import bind_space
from lfm_studio.engine.optimize.mla_cells import SYMMETRIES, MLAPlane
from lfm_studio.engine.optimize.objectives import CRB_BACKGROUND, CRB_PHOTONS, sign
from lfm_studio.engine.optimize.study import (
    DEFAULT_STUDY_NAME,
    load_study,
    record_of,
    run_study,
    stored_crop,
    stored_without_options,
    unchecked_text,
)
from lfm_studio.engine.optimize.task_score import TASK_PHOTONS
from lfm_studio.engine.performance import compute_design_metrics
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.simulation import simulate_psf
from lfm_studio.engine.systems.kinds import kind_of
from lfm_studio.ui.edits import read_path
from lfm_studio.ui.parameter_fields import FIELDS
from lfm_studio.ui.unit_text import shown_unit

SAMPLERS: tuple[str, ...] = ("grid", "tpe", "random")
"""Samplers the dock offers (``grid`` tries every grid point in order, up to the budget)."""

METHODS: dict[str, str] = {
    "grid": "Grid search / design study",
    "algorithm2": "Algorithm 2: MLA layout",
    "gradient-psf": "Gradient: PSF engineering",
    "gradient-end-to-end": "Gradient: end to end",
}
"""The dock's methods (key: label), grid search first (the default)."""

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
    crb_photons, crb_background : ``axial_crb``'s photons per emitter and background, photons per
        pixel (:data:`CRB_OBJECTIVES` only: the task scores' photons are per image).
    """

    parameters: tuple[FreeParameter, ...]
    objectives: tuple[str, ...]
    sampler: str = "grid"
    budget: int = 4
    study: str | None = None
    resume: bool = False
    crop: int | None = DEFAULT_CROP
    objective_options: dict[str, Any] = field(default_factory=dict)
    crb_photons: float = CRB_PHOTONS
    crb_background: float = CRB_BACKGROUND

    def __post_init__(self) -> None:
        _crb_ok(self.crb_photons, self.crb_background)
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

    method: ClassVar[str] = "grid"

    def columns(self) -> tuple[str, ...]:
        """The row parameters the dock's table shows (the freed paths)."""
        return tuple(p.path for p in self.parameters)


@dataclass(frozen=True)
class CandidateRow:
    """One stored candidate: trial number, parameters, objective values, feasibility, design JSON.

    ``note`` says what the row is when it is more than a candidate ("final design", "accepted").
    ``values`` is None for an infeasible candidate; an objective missing from a feasible row's
    ``values`` was not evaluated at that row's design (shown :data:`NOT_EVALUATED`, not plotted).
    """

    number: int
    params: dict[str, Any]
    values: dict[str, float] | None
    reason: str | None
    message: str
    design_json: str | None
    note: str = ""

    @property
    def feasible(self) -> bool:
        return self.values is not None

    @property
    def label(self) -> str:
        """How messages name the row: "candidate 3", or "the final design (step 5)"."""
        if self.note.startswith("final"):
            return f"the {self.note} (row {self.number})"
        return f"candidate {self.number}"

    def design(self) -> Design:
        """The candidate's design (refused for an infeasible candidate, which has none)."""
        if self.design_json is None:
            raise ValueError(f"{self.label} is infeasible ({self.reason}): it has no design to load.")
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


NOT_EVALUATED = "not evaluated"


def reason_tip(code: str | None) -> str:
    """What an infeasibility code means (one sentence), or "" for a feasible row."""
    if not code:
        return ""
    return f"{code}: {REASONS.get(code, 'see the message of this row')}"


def reasons_tip() -> str:
    """Every infeasibility code with its meaning (the tooltip of the table's reason column)."""
    return "Why a candidate is infeasible:\n" + "\n".join(f"{code}: {text}" for code, text in REASONS.items())


def column_labels(design: Design) -> dict[str, str]:
    """``{path: "Label (unit)"}`` of the values ``design`` offers to free (the parameter table's labels)."""
    return {f.path: f"{f.label} ({f.unit})" if f.unit else f.label for f in freeable_fields(design)}


def best_so_far(rows: Sequence[CandidateRow], name: str, direction: str) -> list[float | None]:
    """The best feasible value of objective ``name`` after each row (None before the first feasible one;
    a row where ``name`` was not evaluated does not count)."""
    s, best, out = sign(direction), None, []
    for row in rows:
        if row.values is not None and name in row.values:
            v = row.values[name]
            if best is None or s * v < s * best:
                best = v
        out.append(best)
    return out


def best_row(rows: Sequence[CandidateRow], name: str, direction: str) -> CandidateRow | None:
    """The feasible row with the best value of ``name`` (first one on ties)."""
    feasible = [r for r in rows if r.values is not None and name in r.values]
    if not feasible:
        return None
    s = sign(direction)
    return min(feasible, key=lambda r: s * r.values[name])  # type: ignore[index]


def resume_note(request: Any) -> str:
    """The note for a grid request that resumes a study stored without objective options (their
    check was skipped: :class:`~lfm_studio.engine.optimize.study.StudyOptionsUncheckedWarning`), else ""."""
    if not (isinstance(request, OptimiseRequest) and request.resume and request.study):
        return ""
    path = str(Path(request.study).expanduser())
    return unchecked_text(DEFAULT_STUDY_NAME) if stored_without_options(path, DEFAULT_STUDY_NAME) else ""


def run_optimisation(
    base: Design,
    request: OptimiseRequest,
    *,
    on_row: Callable[[CandidateRow], None] | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> list[CandidateRow]:
    """Run ``request`` from ``base``; returns every stored candidate (resumed ones too) in trial order."""
    objectives = [
        build_objective(n, request.objective_options, request.crb_photons, request.crb_background)
        for n in request.objectives
    ]
    stored, crop = (
        stored_crop(str(Path(request.study).expanduser()), DEFAULT_STUDY_NAME)
        if request.resume and request.study
        else (False, None)
    )
    evaluator = Evaluator(
        base, request.space(), objectives, settings=EvaluationSettings(crop=crop if stored else request.crop)
    )  # raises ValueError naming a path the design does not have; a resumed study keeps its crop
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


# ----- the other methods: Algorithm 2 (MLA layout) and gradient optimisation -----

CLI_CROP = 256  # camera pixels simulated about the axis by Algorithm 2 and gradient runs (the CLI's --crop)


def cell_text(value: Any) -> str:
    """A table cell: numbers to 6 significant digits, None empty, anything else as text."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int | float):
        return f"{value:.6g}"
    return str(value)


@dataclass(frozen=True)
class RunResult:
    """What an Algorithm 2 or gradient run hands the dock.

    rows : one per layout considered / per step, then (gradient) the final design.
    chosen : the ``number`` of the row the engine picked (best layout, final design); None: none feasible.
    summary : one line for the dock's message.
    details : the engine's numbers (start / final values, held-out losses, the precision check).
    """

    rows: list[CandidateRow]
    chosen: int | None = None
    summary: str = ""
    details: dict[str, Any] = field(default_factory=dict)


def _whole(value: Any, name: str, minimum: int = 1) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ValueError(f"{name} must be a whole number >= {minimum}; got {value!r}.")


def _positive(value: Any, name: str, unit: str = "") -> None:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not (math.isfinite(value) and value > 0)
    ):
        raise ValueError(f"{name} must be a positive number{' of ' + unit if unit else ''}; got {value!r}.")


CRB_OBJECTIVES: tuple[str, ...] = ("axial_crb",)
"""Objectives whose photons count per emitter (the dock's CRB photons and background reach only them)."""


def build_objective(name: str, options: dict[str, Any], photons: float, background: float) -> Any:
    """The objective ``name`` with ``options``; an objective of :data:`CRB_OBJECTIVES` also gets
    ``photons`` (per emitter) and ``background`` (photons per pixel), the task scores keep theirs
    (per image), as ``lfm-studio optimize`` gives each objective its engine default."""
    if name in CRB_OBJECTIVES:
        options = {**options, "photons": photons, "background": background}
    return objective_named(name, options)


def _crb_ok(photons: float | None, background: float) -> None:
    """Photons (None: the objective's default) > 0 and a background >= 0 photons per pixel."""
    if photons is not None:
        _positive(photons, "Photons")
    if not (
        isinstance(background, int | float) and not isinstance(background, bool) and math.isfinite(background)
        and background >= 0
    ):  # fmt: skip
        raise ValueError(f"Background must be a number >= 0 photons per pixel; got {background!r}.")


def _crop_ok(crop: int | None) -> None:
    if crop is not None:
        _whole(crop, "PSF crop (px)")


def parse_sizes(text: str) -> tuple[int, ...] | None:
    """The dock's Algorithm 2 "Sizes" text: blank -> None (every size 1 .. M - 1), else cells, comma-separated."""
    text = text.strip()
    if not text:
        return None
    try:
        sizes = tuple(int(v) for v in text.replace(";", ",").split(",") if v.strip())
    except ValueError:
        raise ValueError(
            f"Sizes must be whole numbers of cells separated by commas; got {text!r}. Fix: e.g. 2,3 "
            "(or leave it blank for every size)."
        ) from None
    for size in sizes:
        _whole(size, "Sizes (cells)")
    return sizes or None


def default_min_lenslet_um(design: Design) -> float:
    """A cell size for Algorithm 2: four cells across the pupil at the MLA (µm, 2 significant digits).

    The CLI has no default (``--min-lenslet-um`` is required); the search costs about
    ``M**4 / 4`` layouts for ``M`` cells per side, so the dock starts small."""
    pupil = getattr(design, "pupil_diameter_at_mla", None)  # metres; None for a conventional LFM
    pupil_um = float(pupil) * 1e6 if isinstance(pupil, int | float) else math.nan
    if not (math.isfinite(pupil_um) and pupil_um > 0):
        return 1000.0
    cell = pupil_um / 4
    return float(f"{cell:.2g}")


def algorithm2_cells(design: Design, min_lenslet_um: float) -> int:
    """Cells per side ``M`` of the Algorithm 2 grid of ``design`` with cells of ``min_lenslet_um`` µm."""
    return MLAPlane.from_design(design, float(min_lenslet_um)).cells


@dataclass(frozen=True)
class Algorithm2Request:
    """One Algorithm 2 run of the dock (the options of ``lfm-studio optimize --algorithm2``).

    objective : one registered objective (Algorithm 2 is greedy on one score).
    min_lenslet_um : the cell size ``d_min`` (µm): the smallest lenslet, ``M = floor(pupil / d_min)``.
    symmetry : one of :data:`~lfm_studio.engine.optimize.mla_cells.SYMMETRIES`.
    sizes : block sizes tried, in cells (None: 1 .. M - 1).
    crop : camera pixels simulated about the axis for PSF objectives (None: the whole sensor).
    crb_photons, crb_background : as :class:`OptimiseRequest`.
    """

    method: ClassVar[str] = "algorithm2"
    objective: str = "axial_crb"
    min_lenslet_um: float = 1000.0
    symmetry: str = "none"
    sizes: tuple[int, ...] | None = None
    crop: int | None = CLI_CROP
    seed: int = 0
    crb_photons: float = CRB_PHOTONS
    crb_background: float = CRB_BACKGROUND

    def __post_init__(self) -> None:
        _crb_ok(self.crb_photons, self.crb_background)
        if self.objective not in objective_names():
            raise ValueError(
                f"Objective {self.objective!r} is not a registered objective. Fix: pick one of the list."
            )
        _positive(self.min_lenslet_um, "Minimum lenslet size", "µm")
        if self.symmetry not in SYMMETRIES:
            raise ValueError(f"Symmetry must be one of {SYMMETRIES}; got {self.symmetry!r}.")
        if self.sizes is not None:
            if not self.sizes:
                raise ValueError(
                    "Sizes is empty. Fix: give block sizes in cells (e.g. 2,3) or leave it blank."
                )
            for size in self.sizes:
                _whole(size, "Sizes (cells)")
        _crop_ok(self.crop)

    @property
    def objectives(self) -> tuple[str, ...]:
        return (self.objective,)

    def columns(self) -> tuple[str, ...]:
        """The row parameters the dock's table shows."""
        return ("block", "merged into", "lenslets")

    def check(self, design: Design) -> None:
        """Refuse a cell size that leaves the design no grid (ValueError naming the option)."""
        try:
            cells = algorithm2_cells(design, self.min_lenslet_um)
        except ValueError as error:
            raise ValueError(f"Minimum lenslet size {self.min_lenslet_um:g} µm: {error}") from None
        if cells < 2:
            raise ValueError(
                f"Minimum lenslet size {self.min_lenslet_um:g} µm leaves {cells} cell across the pupil: nothing "
                "to merge. Fix: a smaller minimum lenslet size."
            )
        if self.sizes is not None and max(self.sizes) > cells:
            raise ValueError(
                f"Sizes {','.join(map(str, self.sizes))}: the grid has {cells} cells per side. "
                f"Fix: sizes from 1 to {cells}."
            )


def _layout_row(step: LayoutTrial, record: dict[str, Any], name: str) -> CandidateRow:
    params = step.params
    if params["base"] == "initial":
        block = "start: every cell a lenslet"
    else:
        block = f"{params['size']}×{params['size']} cells at ({params['i']}, {params['j']})"
    feasible = step.score is not None
    return CandidateRow(
        number=int(step.index),
        params={"block": block, "merged into": params["base"], "lenslets": len(step.blocks) or None},
        values={name: float(step.score)} if step.score is not None else None,
        reason=record.get("infeasible_reason"),
        message=record.get("infeasible_message") or ("; ".join(step.warnings) if step.warnings else ""),
        design_json=record.get("design_json") if feasible else None,
        note="accepted" if step.accepted else "",
    )


def run_algorithm2_layout(
    base: Design,
    request: Algorithm2Request,
    *,
    on_row: Callable[[CandidateRow], None] | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> RunResult:
    """Run Algorithm 2 on ``base``'s MLA (a temporary study, deleted afterwards); each layout goes to ``on_row``."""
    objective = build_objective(request.objective, {}, request.crb_photons, request.crb_background)
    rows: list[CandidateRow] = []
    layouts: dict[int, str] = {}

    def on_step(step: LayoutTrial, record: dict[str, Any]) -> None:
        row = _layout_row(step, record, objective.name)
        rows.append(row)
        layouts[row.number] = record["layout"]
        if on_row is not None:
            on_row(row)

    scratch = Path(tempfile.mkdtemp(prefix="lfm_algorithm2_"))
    try:
        result, study = run_algorithm2_study(
            base, objective, str(scratch / "study.db"), min_lenslet_um=request.min_lenslet_um,
            symmetry=request.symmetry, sizes=request.sizes, settings=EvaluationSettings(crop=request.crop),
            seed=request.seed, progress=progress, cancel=cancel, on_step=on_step,
        )  # fmt: skip
        study = None  # noqa: F841  (the storage closes before its folder goes)
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    counts = result.counts_text(study=False)
    details = {"score": result.score, "lenslets": len(result.blocks), "history": list(result.history),
               "evaluated": result.evaluated, "scored": result.scored, "infeasible": result.infeasible}  # fmt: skip
    if result.design is None:
        return RunResult(rows, None, f"no layout was feasible ({counts}).", details)
    key = layout_key(result.blocks)
    chosen = next(r.number for r in rows if r.feasible and layouts[r.number] == key)
    unit = f" {shown_unit(objective.unit)}" if objective.unit else ""
    count = len(result.blocks)
    summary = (
        f"best layout (row {chosen}): {count} lenslet{'s' * (count != 1)}, {objective.name} = "
        f"{result.score:.6g}{unit} ({counts})"
    )
    if count < 2:
        summary += (
            f". Note: {count} lenslet is no light field: a single view records no depth information "
            f"({objective.name} alone rewards the widest lenslet). Fix: a depth-aware objective (e.g. "
            "axial_crb), or load a layout with several lenslets from the table"
        )
    return RunResult(rows, chosen, summary, details)


GRADIENT_MODES: tuple[str, ...] = ("psf", "end-to-end")
PHANTOMS: tuple[str, ...] = ("beads", "cells")


@dataclass(frozen=True)
class GradientRequest:
    """One gradient run of the dock (the options of ``lfm-studio optimize --gradient``; same defaults).

    mode : "psf" (PSF engineering, :func:`~lfm_studio.engine.optimize.optimize_psf`) or "end-to-end"
        (optics and an unrolled-RL reconstruction on the task loss).
    parameters : the freed values; low / high are the bounds (``points`` is not used).
    photons : per emitter for ``axial_crb`` (PSF mode), per image end to end; None: the default
        (:data:`CRB_PHOTONS`, :data:`TASK_PHOTONS`), as ``--photons``.
    The rest as the CLI flags of the same names (docs/optimize.md).
    """

    mode: str
    parameters: tuple[FreeParameter, ...]
    objective: str = "axial_crb"
    steps: int = 20
    optimizer: str = "adam"
    lr: float = 0.05
    schedule: str = "constant"
    crop: int | None = CLI_CROP
    check_float64: bool = True
    photons: float | None = None
    background: float = CRB_BACKGROUND
    keep_last: bool = False
    reconstruction: str = "unrolled-rl"
    freeze_optics: bool = False
    freeze_reconstruction: bool = False
    lr_reconstruction: float = 0.01
    unrolled_iterations: int = 4
    batch: int = 2
    held_out: int = 4
    phantom: str = "beads"
    seed: int = 0

    def __post_init__(self) -> None:
        if self.mode not in GRADIENT_MODES:
            raise ValueError(f"gradient mode must be one of {GRADIENT_MODES}; got {self.mode!r}.")
        if not self.parameters:
            raise ValueError(
                "no parameter is freed. Fix: tick at least one parameter to optimise (its low / high are the bounds)."
            )
        if self.mode == "psf" and self.objective not in PSF_OBJECTIVES:
            raise ValueError(
                f"Objective must be one of {PSF_OBJECTIVES} (differentiable); got {self.objective!r}."
            )
        _whole(self.steps, "Steps")
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(f"Optimiser must be one of {OPTIMIZERS}; got {self.optimizer!r}.")
        _positive(self.lr, "Learning rate")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"Schedule must be one of {SCHEDULES}; got {self.schedule!r}.")
        _crop_ok(self.crop)
        _crb_ok(self.photons, self.background)
        if self.mode == "end-to-end":
            if self.reconstruction not in RECONSTRUCTIONS:
                raise ValueError(
                    f"Reconstruction must be one of {RECONSTRUCTIONS}; got {self.reconstruction!r}."
                )
            frozen_net = self.freeze_reconstruction or self.reconstruction == "rl"
            if self.freeze_optics and frozen_net:
                raise ValueError(
                    "Freeze optics with a frozen reconstruction leaves nothing to optimise (plain rl has no "
                    "weights). Fix: untick Freeze optics, or train the unrolled-rl reconstruction."
                )
            _positive(self.lr_reconstruction, "Reconstruction learning rate")
            _whole(self.unrolled_iterations, "Unrolled iterations")
            _whole(self.batch, "Batch")
            _whole(self.held_out, "Held-out phantoms")
            if self.phantom not in PHANTOMS:
                raise ValueError(f"Phantom must be one of {PHANTOMS}; got {self.phantom!r}.")

    @property
    def method(self) -> str:
        return f"gradient-{self.mode}"

    @property
    def objectives(self) -> tuple[str, ...]:
        return (self.objective,) if self.mode == "psf" else ("task_loss",)

    def space(self) -> DesignSpace:
        """The bounds of the freed values (continuous: no grid points)."""
        return DesignSpace(
            tuple(Parameter(p.path, low=float(p.low), high=float(p.high)) for p in self.parameters)
        )

    def columns(self) -> tuple[str, ...]:
        return tuple(p.path for p in self.parameters)

    def check(self, design: Design) -> None:
        """Refuse a parameter the gradient path cannot differentiate (the engine's message lists those it can)."""
        bind_space(self.space(), design)


AnyRequest = OptimiseRequest | Algorithm2Request | GradientRequest


def objective_info(request: AnyRequest) -> dict[str, tuple[str, str]]:
    """``{objective name: (direction, unit)}`` of the objectives ``request`` reports (the first ranks)."""
    if isinstance(request, GradientRequest):
        if request.mode == "end-to-end":
            return {"task_loss": ("minimize", "")}
        built = psf_objective(
            request.objective, {"photons": request.photons, "background": request.background}
        )
        return {request.objective: (built.direction, built.unit)}
    out: dict[str, tuple[str, str]] = {}
    for name in request.objectives:
        objective = objective_named(name)
        out[name] = (objective.direction, objective.unit)
    return out


def _step_note(grad_norm: float | None, lr: float | None, backtracks: int, reason: str | None) -> str:
    note = "" if grad_norm is None else f"|grad| {grad_norm:.3g}, lr {lr:.3g}"
    if reason:
        note += f"; update backtracked {backtracks}x: {reason}"
    return note


_STUDY_NAME = "lfm_study"


class _StepWatcher:
    """The progress callback of a gradient run recorded into a temporary study: at each checkpoint the
    steps stored since the last one go to ``on_row`` (the descent reports progress, not its steps; its
    study holds them, one committed trial per step, design JSON included)."""

    def __init__(
        self,
        storage: str,
        name: str,
        on_row: Callable[[CandidateRow], None],
        progress: ProgressCallback | None,
    ) -> None:
        self.storage, self.name, self.on_row, self.progress = storage, name, on_row, progress
        self.study: Any = None
        self.seen: set[int] = set()

    def __call__(self, done: int, total: int, message: str = "") -> None:
        if done > 0:
            self.flush()
        if self.progress is not None:
            self.progress(done, total, message)

    def flush(self) -> None:
        if self.study is None:
            self.study = load_study(self.storage, _STUDY_NAME)
        for trial in self.study.get_trials(deepcopy=False):
            record = record_of(trial)
            step = record.get("gradient")
            if not step or step.get("last") or trial.number in self.seen:
                continue
            self.seen.add(trial.number)
            complete = trial.state.name == "COMPLETE"
            self.on_row(
                CandidateRow(
                    number=int(step["step"]), params=dict(trial.params),
                    values={self.name: float(trial.values[0])} if complete else None,
                    reason=record.get("infeasible_reason"),
                    message=_step_note(step.get("grad_norm"), step.get("lr"), int(step.get("backtracks") or 0),
                                       step.get("backtrack_reason")),
                    design_json=record.get("design_json"),
                )
            )  # fmt: skip


def run_gradient(
    base: Design,
    request: GradientRequest,
    *,
    on_row: Callable[[CandidateRow], None] | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> RunResult:
    """Run the gradient optimiser from ``base``: one row per step, then the final design.

    With ``on_row`` the run is recorded into a temporary study (deleted afterwards) and each step
    goes to ``on_row`` at the next checkpoint (so the loss curve fills in while it runs)."""
    scratch = None if on_row is None else Path(tempfile.mkdtemp(prefix="lfm_gradient_"))
    watcher = None
    if scratch is not None and on_row is not None:
        name = request.objective if request.mode == "psf" else "task_loss"
        watcher = _StepWatcher(str(scratch / "study.db"), name, on_row, progress)
    try:
        return _run_gradient(base, request, watcher, progress, cancel)
    finally:
        if watcher is not None:
            watcher.study = None
        if scratch is not None:
            shutil.rmtree(scratch, ignore_errors=True)


def _run_gradient(
    base: Design,
    request: GradientRequest,
    watcher: _StepWatcher | None,
    progress: ProgressCallback | None,
    cancel: CancelToken,
) -> RunResult:
    from lfm_studio.engine.learned.data import TrainingDataSpec

    space = request.space()
    common: dict[str, Any] = {
        "steps": request.steps, "optimizer": request.optimizer, "lr": request.lr, "schedule": request.schedule,
        "dtype": "float32", "settings": EvaluationSettings(crop=request.crop),
        "check_float64": request.check_float64, "seed": request.seed, "cancel": cancel,
        "progress": progress if watcher is None else watcher,
        "study": None if watcher is None else watcher.storage, "study_name": _STUDY_NAME,
    }  # fmt: skip
    if request.mode == "psf":
        options = {"photons": request.photons, "background": request.background}
        name = request.objective
        unit = psf_objective(name, options).unit
        result = optimize_psf(
            base, space, name, options=options, final="last" if request.keep_last else "best", **common
        )
    else:
        name, unit = "task_loss", ""
        data = TrainingDataSpec(
            phantoms=request.phantom,  # type: ignore[arg-type]
            objects=(4, 10), photons=(TASK_PHOTONS if request.photons is None else request.photons,), seed=request.seed,
        )  # fmt: skip
        result = optimize_end_to_end(
            base, space, reconstruction=request.reconstruction, freeze_optics=request.freeze_optics,
            freeze_reconstruction=request.freeze_reconstruction, lr_reconstruction=request.lr_reconstruction,
            iterations=request.unrolled_iterations, batch=request.batch, held_out=request.held_out, data=data,
            **common,
        )  # fmt: skip
    rows = []
    for step in result.history:
        finite = math.isfinite(step.value)
        at, _ = quietly(lambda point=step.point: space.apply(base, point))  # type: ignore[misc]
        note = _step_note(step.grad_norm, step.lr, step.backtracks, step.infeasible)
        rows.append(
            CandidateRow(
                number=step.step, params=dict(step.point), values={name: step.value} if finite else None,
                reason=None if finite else "not_finite", message=note, design_json=design_to_json(at),
            )
        )  # fmt: skip
    final_point = result.final_point or {p: float(v) for p, v in space.values_of(result.design).items()}
    chosen = len(result.history)
    notes = list(result.warnings)
    if request.mode == "end-to-end":
        # final_value is the last step's training loss, measured at the point *before* its update:
        # nothing was measured on the training batches at the final point, only the held-out loss.
        final_values: dict[str, float] = {}
        notes.insert(
            0,
            f"{name} {NOT_EVALUATED} at the final design (each step's training loss is measured before "
            f"its update); held-out task loss at the final design {result.extra['held_out_final']:.4g}",
        )
    else:  # PSF engineering: final_value is the objective evaluated at the final point
        final_values = {name: result.final_value}
    rows.append(
        CandidateRow(
            number=chosen, params=dict(final_point), values=final_values, reason=None,
            message="; ".join(notes), design_json=design_to_json(result.design),
            note=f"final design ({result.final} point)",
        )
    )  # fmt: skip
    unit_text = f" {shown_unit(unit)}" if unit else ""
    details: dict[str, Any] = {
        "start_value": result.start_value,
        "final_value": result.final_value,
        **result.extra,
    }
    if request.mode == "psf":
        summary = (
            f"{name}: start {result.start_value:.6g}, final {result.final_value:.6g}{unit_text} after "
            f"{len(result.history)} {request.optimizer} steps (the final design is the {result.final} point)"
        )
    else:
        extra = result.extra
        last = len(result.history) - 1
        summary = (
            f"held-out task loss {extra['held_out_start']:.4g} at the start → {extra['held_out_final']:.4g} at the "
            f"final design (all-zero volume {extra['zero_floor']:g}); training-batch loss {result.start_value:.4g} "
            f"at step 0, {result.final_value:.4g} at step {last} (before its update; {NOT_EVALUATED} at the "
            "final design)"
        )
        if extra.get("final_volume_trivial"):
            summary += f"; the final reconstruction is {extra['final_volume_trivial']}"
    if result.check is not None:
        details["check_error"] = result.check.relative_error
        verdict = "within" if result.check.passed else "OUTSIDE"
        summary += (
            f"; float32 vs float64 start gradient differ by {result.check.relative_error:.2g} ({verdict} "
            f"{result.check.tolerance:g})"
        )
    return RunResult(rows, chosen, summary, details)


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
