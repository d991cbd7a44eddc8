"""Stored, resumable studies on Optuna's RDB storage (SQLite by default, PostgreSQL by URL).

:func:`run_study` evaluates points of a design space with an :class:`~.evaluate.Evaluator`
and stores every candidate as an Optuna trial: parameters, objective values, and in one
user attribute ``record`` (one database commit) the seconds per stage, the candidate's
design JSON, the seed, design warnings, per-lenslet cache use, and for an infeasible
point its reason (the trial is then ``FAIL`` with ``record["infeasible_reason"]``). The study itself stores the base design, the space, the
objectives (name, unit, direction), their options (``objective_options``: photons, iterations,
seeds...; what changes a score), the simulation settings and the sampler.

Resuming (``resume=True``) is refused when any of these differ (each differing objective option
is named with both values); a study stored before objective options were recorded resumes with a
:class:`StudyOptionsUncheckedWarning`. It continues where a killed run stopped and never evaluates a
stored candidate again: the grid sampler enqueues only grid points without a stored
result, in grid order; for the other samplers a proposed point that is already stored
gets the stored values copied (``record["reused_from"]``) instead of an evaluation.
A trial left ``RUNNING`` by a killed process is closed as ``FAIL`` without a record (no
result) and its point evaluated again.

Samplers (:data:`SAMPLERS`): ``grid`` (every grid point, in order: enumerated here rather
than by Optuna's ``GridSampler``, which visits points in random order and can repeat one
under parallel workers), ``tpe``, ``cmaes`` (the ``cmaes`` package, in the optimize extra) and ``random``.

Parallel evaluation: pass a Dask ``client`` (``dask.distributed.Client``; a local cluster,
or a scheduler address for a cluster); ``client=None`` evaluates in this process. Each
Dask worker keeps its own per-lenslet cache (the evaluator is scattered once).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Callable, Mapping, Sequence
from itertools import islice
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.design_io import design_to_json
from lfm_studio.engine.design.space import DesignSpace, Parameter, point_key
from lfm_studio.engine.io.file_checks import OutputError
from lfm_studio.engine.optimize.evaluate import EvaluationRecord, Evaluator
from lfm_studio.engine.optimize.objectives import score_options
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint

if TYPE_CHECKING:
    import optuna

SAMPLERS: tuple[str, ...] = ("grid", "tpe", "cmaes", "random")
DEFAULT_STUDY_NAME = "lfm_study"
INSTALL_HINT = 'pip install "lfm-studio[optimize]" (optuna and SQLAlchemy)'

TrialCallback = Callable[["optuna.Study", "optuna.trial.FrozenTrial", EvaluationRecord | None], None]


class StudyMismatchError(ValueError):
    """A stored study was made for another space, objectives, objective options or base design."""


class StudyExistsError(OutputError):
    """The study name is taken and the run was not asked to resume it (the CLI exits 3, output refused)."""


class StudyOptionsUncheckedWarning(UserWarning):
    """A resumed study was stored before objective options were recorded: they could not be compared."""


def require_optuna() -> Any:
    """The ``optuna`` module, or a ``ValueError`` saying how to install it (the CLI exits 2)."""
    try:
        import optuna
    except ImportError as error:  # pragma: no cover - optuna is in the dev extra
        raise ValueError(f"studies need Optuna, which is not installed. Fix: {INSTALL_HINT}.") from error
    optuna.logging.set_verbosity(optuna.logging.ERROR)  # infeasible trials are FAIL by design
    return optuna


def storage_url(storage: str) -> str:
    """A database URL: a URL (``sqlite:///study.db``, ``postgresql://...``) as is, a file path as SQLite."""
    if "://" in storage:
        return storage
    return f"sqlite:///{Path(storage).expanduser().resolve()}"


def _sqlite_pragmas(connection: Any, _record: Any) -> None:
    cursor = connection.cursor()
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA synchronous=NORMAL")
    cursor.close()


def make_storage(storage: str) -> Any:
    """Optuna's RDB storage for ``storage`` (a URL or a SQLite file path).

    SQLite runs in WAL mode with ``synchronous=NORMAL``: every trial is still committed before
    the next starts, so a killed process loses nothing stored (resume relies on that); only an
    OS crash or power loss can drop the last commits, whose points then run again. It halves
    the cost of a trial's commits here (about 0.23 s -> 0.13 s per trial on this disk).
    """
    optuna = require_optuna()
    url = storage_url(storage)
    rdb = optuna.storages.RDBStorage(url)
    if url.startswith("sqlite:"):
        from sqlalchemy import event

        event.listen(rdb.engine, "connect", _sqlite_pragmas)
        rdb.engine.dispose()  # pooled connections reopen with the pragmas
    return rdb


def distributions(space: DesignSpace) -> dict[str, Any]:
    """Optuna distributions of the parameters (choices and ``points`` grids are categorical)."""
    optuna = require_optuna()
    d = optuna.distributions
    out: dict[str, Any] = {}
    for p in space.parameters:
        if p.choices is not None or p.points is not None:
            out[p.path] = d.CategoricalDistribution(p.grid())
        else:
            assert p.low is not None and p.high is not None  # Parameter's checks: bounds without choices
            if p.integer:
                out[p.path] = d.IntDistribution(int(p.low), int(p.high), log=p.log, step=int(p.step or 1))
            else:
                out[p.path] = d.FloatDistribution(p.low, p.high, log=p.log, step=None if p.log else p.step)
    return out


def make_sampler(name: str, seed: int) -> Any:
    """The Optuna sampler ``name`` (:data:`SAMPLERS`; ``grid`` is driven by :func:`run_study`)."""
    optuna = require_optuna()
    if name not in SAMPLERS:
        raise ValueError(f"sampler must be one of {SAMPLERS}; got {name!r}.")
    if name == "cmaes":
        try:
            import cmaes  # noqa: F401
        except ImportError as error:
            raise ValueError(
                "sampler 'cmaes' needs the cmaes package. Fix: pip install cmaes, or use 'tpe'."
            ) from error
        return optuna.samplers.CmaEsSampler(seed=seed)
    if name == "tpe":
        return optuna.samplers.TPESampler(seed=seed)
    return optuna.samplers.RandomSampler(seed=seed)


def objective_attrs(objective: Any) -> dict[str, str]:
    """How a study names an objective: ``{"name", "unit", "direction"}`` of anything that has them."""
    return {"name": objective.name, "unit": objective.unit, "direction": objective.direction}


def objective_options(objectives: Sequence[Any]) -> dict[str, dict[str, Any]]:
    """``{name: options}`` of the objectives (:func:`.objectives.score_options`): what a study stores
    under ``objective_options`` and a resume must repeat."""
    return {o.name: score_options(o) for o in objectives}


def study_description(
    base: Design,
    space: Mapping[str, Any],
    objectives: Sequence[Mapping[str, str]],
    settings: Mapping[str, Any],
    sampler: str,
    seed: int,
    options: Mapping[str, Mapping[str, Any]] | None = None,
) -> dict[str, Any]:
    """The study attributes every search stores once (a resumed run must match them,
    :func:`open_stored`): the base design's JSON, the space (``DesignSpace.to_dict`` or another
    search's description), the objectives (:func:`objective_attrs`), the objective options
    (:func:`objective_options`; None: the objectives take none), the settings, the sampler name
    and the seed."""
    return {
        "base_design": design_to_json(base),
        "space": dict(space),
        "objectives": [dict(o) for o in objectives],
        "objective_options": {k: dict(v) for k, v in (options or {}).items()},
        "settings": dict(settings),
        "sampler": sampler,
        "seed": seed,
    }


def study_attrs(evaluator: Evaluator, sampler: str) -> dict[str, Any]:
    """What a study of ``evaluator``'s points is about (:func:`study_description`)."""
    return study_description(
        evaluator.base,
        evaluator.space.to_dict(),
        [objective_attrs(o) for o in evaluator.objectives],
        evaluator.settings.to_dict(),
        sampler,
        evaluator.seed,
        objective_options(evaluator.objectives),
    )


COMPARED: dict[str, tuple[str, str]] = {
    "space": ("another space", "this one"),
    "objectives": ("other objectives", "these"),
    "base_design": ("another base design", "this one"),
    "settings": ("other settings", "these"),
    "seed": ("another seed", "this one"),
}
"""The study attributes a resume must repeat: key -> (how the refusal names another one, "this one" / "these")."""


def _check_same(study: Any, attrs: dict[str, Any]) -> None:
    stored = study.user_attrs
    for key, (other, this) in COMPARED.items():
        if key in stored and json.dumps(stored[key], sort_keys=True) != json.dumps(
            attrs[key], sort_keys=True
        ):
            differs = _differences(stored[key], attrs[key])
            raise StudyMismatchError(
                f"study {study.study_name!r} was made with {other}{differs}; resuming it with {this} would mix "
                f"candidates of two searches. Fix: give the same {key.replace('_', ' ')} as before, or a new "
                "--study-name / database."
            )
    _check_options(study, stored.get(OPTIONS), attrs.get(OPTIONS) or {})


OPTIONS = "objective_options"
"""The study attribute holding :func:`objective_options` (absent in studies stored before it)."""


def _check_options(study: Any, stored: Any, now: Mapping[str, Mapping[str, Any]]) -> None:
    """Refuse a resume whose objective options differ from the stored ones, naming each (both
    values); warn when the study predates stored options (:class:`StudyOptionsUncheckedWarning`)."""
    if stored is None:
        warnings.warn(StudyOptionsUncheckedWarning(unchecked_text(study.study_name)), stacklevel=3)
        return
    differs = option_differences(stored, now)
    if differs:
        raise StudyMismatchError(
            f"study {study.study_name!r} was scored with other objective options ({'; '.join(differs)}); resuming "
            "it with these would rank scores of two settings together. Fix: resume with the stored options, "
            "or start a new --study-name / database."
        )


def unchecked_text(study_name: str) -> str:
    """What a resume of a study stored without objective options says (:class:`StudyOptionsUncheckedWarning`)."""
    return (
        f"study {study_name!r} was stored without its objective options (photons, iterations, seeds...), so "
        "this resume could not check that its candidates are scored as before. Fix: resume only with the "
        "options of the first run, or start a new --study-name / database."
    )


def stored_without_options(storage: str, study_name: str | None = None) -> bool:
    """True when a stored study predates stored objective options (a resume cannot check them);
    False for a study that has them, or none stored yet (the run reports that)."""
    try:
        attrs = load_study(storage, study_name).user_attrs
    except (FileNotFoundError, ValueError, KeyError):
        return False
    return OPTIONS not in attrs


def option_differences(stored: Mapping[str, Any], now: Mapping[str, Any]) -> list[str]:
    """``"OBJECTIVE OPTION: stored X, now Y"`` for every option that differs (missing: ``None``)."""
    out = []
    for name in sorted({*stored, *now}):
        old, new = stored.get(name) or {}, now.get(name) or {}
        for key in sorted({*old, *new}):
            if json.dumps(old.get(key), sort_keys=True) != json.dumps(new.get(key), sort_keys=True):
                out.append(f"{name} {key}: stored {old.get(key)!r}, now {new.get(key)!r}")
    return out


def _differences(stored: Any, now: Any) -> str:
    """`` (key: stored X, now Y; ...)`` for two dicts (at most 4 keys), else ``""``."""
    if not (isinstance(stored, dict) and isinstance(now, dict)):
        return ""
    keys = sorted(k for k in {*stored, *now} if stored.get(k) != now.get(k))[:4]
    if not keys:
        return ""
    return " (" + "; ".join(f"{k}: stored {stored.get(k)!r}, now {now.get(k)!r}" for k in keys) + ")"


def stored_crop(storage: str, study_name: str | None = None) -> tuple[bool, int | None]:
    """``(True, crop)`` of the PSF crop a stored study was run with, else ``(False, None)`` (no such
    study or database yet, or settings without a crop): a resumed study keeps it, whatever the
    automatic crop of its design is now (:meth:`EvaluationSettings.for_design`)."""
    try:
        settings = load_study(storage, study_name).user_attrs.get("settings") or {}
    except (FileNotFoundError, ValueError, KeyError):  # not there yet: the run reports it
        return False, None
    return ("crop" in settings), settings.get("crop")


EXISTS_FIX = "pass --resume to continue it, or choose another --study-name or database."
"""How to get past an existing study (the end of :func:`open_stored`'s refusal)."""


def open_study(
    evaluator: Evaluator,
    storage: str,
    *,
    study_name: str = DEFAULT_STUDY_NAME,
    sampler: str = "grid",
    resume: bool = False,
) -> Any:
    """Create the study, or (``resume=True``) load it after checking it is the same search."""
    return open_stored(
        study_attrs(evaluator, sampler),
        [o.direction for o in evaluator.objectives],
        storage,
        study_name=study_name,
        sampler=make_sampler("random" if sampler == "grid" else sampler, evaluator.seed),
        resume=resume,
    )


def open_stored(
    attrs: dict[str, Any],
    directions: Sequence[str],
    storage: str,
    *,
    study_name: str = DEFAULT_STUDY_NAME,
    sampler: Any = None,
    resume: bool = False,
    exists_fix: str = EXISTS_FIX,
) -> Any:
    """Create a study described by ``attrs`` (:func:`study_description` keys), or (``resume=True``) load
    it after checking that its stored ``attrs`` match (:class:`StudyMismatchError` otherwise). An
    existing study without ``resume`` is refused with a :class:`StudyExistsError` (a ``ValueError``) ending
    in ``Fix: <exists_fix>``."""
    optuna = require_optuna()
    url = storage_url(storage)
    rdb = make_storage(storage)
    names = optuna.study.get_all_study_names(storage=rdb)
    exists = study_name in names
    if exists and not resume:
        raise StudyExistsError(f"study {study_name!r} already exists in {url}. Fix: {exists_fix}")
    study = optuna.create_study(
        storage=rdb,
        study_name=study_name,
        directions=list(directions),
        sampler=sampler,
        load_if_exists=True,
    )
    if exists:
        _check_same(study, attrs)
    else:
        for key, value in attrs.items():
            study.set_user_attr(key, value)
    return study


RECORD = "record"
"""The user attribute holding a trial's :meth:`EvaluationRecord.attrs` (one write: one commit)."""


def record_of(trial: Any) -> dict[str, Any]:
    """The stored record of a trial (empty for a trial without one)."""
    return dict(trial.user_attrs.get(RECORD) or {})


def _finished(trial: Any) -> bool:
    """A trial with a result: complete, or failed as infeasible (not interrupted)."""
    state = trial.state.name
    return state == "COMPLETE" or (state == "FAIL" and record_of(trial).get("infeasible_reason") is not None)


def _close_interrupted(study: Any) -> None:
    """Mark trials left RUNNING by a killed process as FAIL (interrupted), so their points run again."""
    for trial in study.get_trials(deepcopy=False):
        if trial.state.name == "RUNNING":  # FAIL without infeasible_reason: no result
            study.tell(trial.number, state=_state("FAIL"), skip_if_finished=True)


def _fail_unfinished(study: Any, trials: Sequence[Any]) -> None:
    """Mark this run's ``trials`` that have no result as FAIL (interrupted): after a Ctrl+C the
    study does not list them as running, and ``resume`` evaluates their points again."""
    for trial in trials:
        study.tell(trial.number, state=_state("FAIL"), skip_if_finished=True)


def _state(name: str) -> Any:
    return getattr(require_optuna().trial.TrialState, name)


def _tell(study: Any, trial: Any, record: EvaluationRecord, names: Sequence[str]) -> None:
    trial.set_user_attr(RECORD, record.attrs())
    if record.values is None:
        study.tell(trial, state=_state("FAIL"))
    else:
        study.tell(trial, [record.values[n] for n in names])


def _reuse(study: Any, trial: Any, stored: Any) -> None:
    """Close ``trial`` with the result of the ``stored`` trial of the same point (no evaluation)."""
    trial.set_user_attr(RECORD, {**record_of(stored), "reused_from": stored.number})
    if stored.state.name == "COMPLETE":
        study.tell(trial, list(stored.values))
    else:
        study.tell(trial, state=_state("FAIL"))


def _stored(study: Any) -> dict[str, Any]:
    return {point_key(t.params): t for t in study.get_trials(deepcopy=False) if _finished(t)}


def run_study(
    evaluator: Evaluator,
    storage: str = "sqlite:///lfm_study.db",
    *,
    study_name: str = DEFAULT_STUDY_NAME,
    sampler: str = "grid",
    n_trials: int | None = None,
    resume: bool = False,
    client: Any = None,
    callbacks: Sequence[TrialCallback] = (),
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> Any:
    """Run (or resume) a stored search; returns the ``optuna.Study``.

    Parameters
    ----------
    evaluator : scores one point (its space, objectives and settings define the study).
    storage : database URL (SQLite file by default; ``postgresql://user@host/db`` for a cluster) or a file path.
    study_name : the study in that database.
    sampler : one of :data:`SAMPLERS`.
    n_trials : total trials the study should hold (earlier runs count); None = the whole grid
        (``grid``) or 20 (other samplers).
    resume : continue an existing study (refused when it was made for another search).
    client : a ``dask.distributed.Client`` to evaluate on (None: in this process); trials are
        proposed in batches of the client's worker count.
    callbacks : ``callback(study, trial, record)`` after each stored trial (``record`` None when reused).
    progress, cancel : as everywhere in the engine (cancel stops between batches).

    A ``KeyboardInterrupt`` (Ctrl+C) marks the trials being evaluated as failed (interrupted)
    before it propagates; the finished trials stay stored.
    """
    study = open_study(evaluator, storage, study_name=study_name, sampler=sampler, resume=resume)
    _close_interrupted(study)
    asked: list[Any] = []  # the trials of the batch being evaluated
    try:
        _run_trials(study, evaluator, sampler, n_trials, client, callbacks, progress, cancel, asked)
    except KeyboardInterrupt:
        _fail_unfinished(study, asked)
        raise
    return study


def _run_trials(
    study: Any,
    evaluator: Evaluator,
    sampler: str,
    n_trials: int | None,
    client: Any,
    callbacks: Sequence[TrialCallback],
    progress: ProgressCallback | None,
    cancel: CancelToken,
    asked: list[Any],
) -> None:
    """The loop of :func:`run_study`; ``asked`` holds the batch being evaluated."""
    dists = distributions(evaluator.space)
    names = [o.name for o in evaluator.objectives]
    if sampler == "grid":
        grid = list(evaluator.space.grid())
        total = len(grid) if n_trials is None else min(n_trials, len(grid))
    else:
        grid, total = [], 20 if n_trials is None else n_trials
    keys = [point_key(p) for p in grid]
    cursor = 0  # grid points before it all have a stored result (stored results only grow)
    remote = None if client is None else client.scatter(evaluator, broadcast=True)
    batch_size = 1 if client is None else max(1, len(client.scheduler_info().get("workers", {})))
    while True:
        stored = _stored(study)
        done = (
            len(stored)
            if sampler == "grid"
            else sum(1 for t in study.get_trials(deepcopy=False) if _finished(t))
        )
        checkpoint(cancel, progress, min(done, total), total, f"{done}/{total} candidates")
        if done >= total:
            break
        if sampler == "grid":
            while cursor < len(grid) and keys[cursor] in stored:
                cursor += 1
            want = min(batch_size, total - done)
            pending = list(islice((grid[i] for i in range(cursor, len(grid)) if keys[i] not in stored), want))
            for point in pending:
                study.enqueue_trial(point)
            asks = len(pending)
        else:
            asks = min(batch_size, total - done)
        asked.clear()
        for _ in range(asks):  # one at a time: an interrupt between asks still finds the earlier ones
            asked.append(study.ask(dists))
        trials = list(asked)
        todo = []
        for trial in trials:
            key = point_key(trial.params)
            if key in stored:
                _reuse(study, trial, stored[key])
                for callback in callbacks:
                    callback(study, study.get_trials(deepcopy=False)[trial.number], None)
            else:
                todo.append(trial)
        if client is None:
            records = [evaluator(t.params) for t in todo]
        else:
            records = client.gather([client.submit(_evaluate, remote, t.params, pure=False) for t in todo])
        for trial, record in zip(todo, records, strict=True):
            _tell(study, trial, record, names)
            for callback in callbacks:
                callback(study, study.get_trials(deepcopy=False)[trial.number], record)


def _evaluate(evaluator: Evaluator, params: dict[str, Any]) -> EvaluationRecord:
    """Evaluate on a Dask worker (module level so it pickles)."""
    return evaluator(params)


def load_study(storage: str, study_name: str | None = None) -> Any:
    """A stored study (the only one in the database when ``study_name`` is None)."""
    optuna = require_optuna()
    url = storage_url(storage)
    if "://" not in storage and not Path(storage).expanduser().is_file():
        raise FileNotFoundError(
            f"{storage}: no such study database. Fix: give the file of a study (e.g. study.db)."
        )
    rdb = make_storage(storage)
    names = optuna.study.get_all_study_names(storage=rdb)
    if study_name is None:
        if len(names) != 1:
            raise ValueError(f"{url} holds studies {names}; name one with --study-name.")
        study_name = names[0]
    if study_name not in names:
        raise ValueError(f"{url} has no study {study_name!r}; it holds {names}.")
    return optuna.load_study(study_name=study_name, storage=rdb)


def space_of(study: Any) -> DesignSpace:
    """The design space a study was made with."""
    return DesignSpace(tuple(Parameter.from_dict(p) for p in study.user_attrs["space"]["parameters"]))
