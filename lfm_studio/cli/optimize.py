"""``lfm-studio optimize`` (a stored, resumable design search) and ``lfm-studio study show``.

``optimize DESIGN --space space.json --objective NAME[,NAME] --study sqlite:///study.db --out best.json``
evaluates the space's points (grid by default, or an Optuna sampler) on the objectives,
stores every candidate in the study database, prints the best design and writes it as a
design file. ``--resume`` continues a stored study without evaluating any stored candidate
again; ``--workers N`` evaluates on a local Dask cluster. ``study show STUDY`` prints the
trials and the best candidate (one objective) or the Pareto front (several).

``optimize DESIGN --algorithm2 --min-lenslet-um D [--symmetry S] [--sizes 2,3] --objective NAME
--study sqlite:///s.db --out best.json`` runs the thesis' Algorithm 2 (greedy merges of
``D``-um cells of the MLA plane) on one objective, recording every layout in the study
(``--resume`` takes stored layouts' scores from it). See docs/optimize.md.

``optimize DESIGN --space space.json --gradient psf --objective axial_crb --steps 20 --out best.json``
descends a differentiable PSF objective through the Fourier fast path or the conventional
patterns (Adam or ``--optimizer lbfgs``; bounds projected after each step; ``--catalogue`` snaps focal lengths at the end);
``--gradient end-to-end`` trains the optics and an unrolled-RL reconstruction jointly on the
task loss (``--freeze-optics`` / ``--freeze-reconstruction``). Every step is a trial of the study.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from lfm_studio.cli.interrupts import on_interrupt, watching
from lfm_studio.cli.progress import progress_bar

DEFAULT_STUDY = "sqlite:///lfm_study.db"


def _floats(text: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in text.split(","))
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers; got {text!r}") from error


def _seeds(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError as error:
        raise argparse.ArgumentTypeError(
            f"--task-seeds must be comma-separated integers; got {text!r}"
        ) from error


def _study_file(url: str) -> str | None:
    """The database file of a SQLite study URL or path (an output the --out must not be)."""
    if url.startswith("sqlite:///"):
        return url.removeprefix("sqlite:///")
    return None if "://" in url else url


def _objectives(args: argparse.Namespace) -> list:
    from lfm_studio.engine.optimize import objective_named

    options = {
        "phantom": args.phantom,
        "method": args.method,
        "iterations": args.iterations,
        "photons": args.photons,
        "background": args.background,
        "seeds": args.task_seeds,
    }
    names = [n.strip() for n in args.objective.split(",") if n.strip()]
    if not names:
        raise ValueError(
            "--objective names no objective. Fix: e.g. --objective task_ncc (see docs/optimize.md)."
        )
    built = [objective_named(name, options) for name in names]
    refuse_unused(args, built)
    return built


UNUSED_CHECKED: dict[str, str] = {"photons": "--photons", "background": "--background"}
"""Objective options whose flag is refused when no objective of the run takes it (default None: not given)."""


def refuse_unused(args: argparse.Namespace, objectives: list) -> None:
    """Refuse ``--photons`` / ``--background`` given for objectives none of which takes it (they
    would be silently ignored), naming the option, its value and the objectives that take it."""
    from lfm_studio.engine.optimize.objectives import score_options

    for key, flag in UNUSED_CHECKED.items():
        value = getattr(args, key)
        if value is not None and not any(key in score_options(o) for o in objectives):
            names = ", ".join(o.name for o in objectives)
            raise ValueError(
                f"{flag} {value:g} does not apply to {names}: no objective of this run takes {key} "
                f"({OPTION_USERS[key]}). Fix: drop {flag}, or add an objective that takes it."
            )


OPTION_USERS: dict[str, str] = {
    "photons": "axial_crb: photons per emitter; task_* objectives and --gradient end-to-end: photons per image",
    "background": "axial_crb only: photons per pixel",
}
"""Which objectives take each checked option, and in what unit (the refusal's explanation)."""


def _constraints(args: argparse.Namespace, design) -> tuple:
    from lfm_studio.engine.optimize import MinimumLensletSize, RequirementsConstraint
    from lfm_studio.engine.optimize.constraints import default_constraints

    found = list(default_constraints(design))
    if args.min_lenslet_um is not None:
        found.append(MinimumLensletSize(args.min_lenslet_um))
    if args.require_zebrafish:
        found.append(RequirementsConstraint())
    return tuple(found)


@contextlib.contextmanager
def _client(args: argparse.Namespace) -> Iterator[Any]:
    """The Dask client the video reconstruction uses too (engine/batch): --scheduler, --workers N > 1
    (a local cluster, closed afterwards), else None (in this process)."""
    if args.scheduler is None and args.workers <= 1:
        yield None
        return
    try:
        from lfm_studio.engine.batch import client_for
    except ImportError as error:
        raise ValueError(f'{error}. Fix: pip install "lfm-studio[scale]", or use --workers 1.') from error
    with client_for(None, None if args.scheduler else args.workers, args.scheduler) as client:
        yield client


def _stored_crop(args: argparse.Namespace) -> tuple[bool, int | None]:
    """``(True, crop)`` of the stored study a ``--resume`` continues, else ``(False, None)``."""
    from lfm_studio.engine.optimize.study import stored_crop

    return stored_crop(args.study, args.study_name) if args.resume else (False, None)


def _crop(args: argparse.Namespace, design) -> int | None:
    """The PSF crop: --crop, else the resumed study's, else :func:`auto_crop` of the design (printed)."""
    from lfm_studio.engine.optimize import auto_crop, crop_views

    automatic = False
    if args.crop is not None:
        if args.crop < 1:
            raise ValueError(
                f"--crop must be a positive number of camera pixels; got {args.crop}. Fix: e.g. --crop 512, "
                "or leave it out for the automatic crop."
            )
        crop = args.crop
    else:
        stored, crop = _stored_crop(args)
        if not stored:
            crop, automatic = auto_crop(design), True
    views = crop_views(design, crop)
    if automatic:
        held = f"; {views.describe()}" if views is not None else ""
        print(
            f"PSF crop: {'the whole sensor' if crop is None else f'{crop} px'} (automatic{held}; --crop to change)"
        )
    elif views is not None and not views.enough:
        print(
            f"warning: --crop {crop}: {views.describe()} of {design.name!r} (fewer than {views.needed}); PSF and task "
            f"objectives then score diffraction tails, not the design's views. Fix: {_crop_fix(design)}, or leave "
            "--crop out.",
            file=sys.stderr,
        )
    return crop


def _crop_fix(design) -> str:
    """The ``--crop`` that holds enough sub-images of ``design`` (:func:`auto_crop`), as a fix."""
    from lfm_studio.engine.optimize import auto_crop

    better = auto_crop(design)
    return (
        f"--crop {better}"
        if better is not None
        else f"--crop {max(design.camera.pixel_count)} (the whole sensor)"
    )


def _settings(args: argparse.Namespace, design):
    from lfm_studio.cli.simulate import parse_depths, resolve_device
    from lfm_studio.engine.optimize import EvaluationSettings
    from lfm_studio.engine.simulation import depth_grid

    depths = parse_depths(args.depths)
    return EvaluationSettings(
        depths_um=None if depths is None else tuple(z * 1e6 for z in depth_grid(depths, "--depths")),
        crop=_crop(args, design),
        device=resolve_device(args.device),
    )


def _floor_warning(record: dict, crop: int | None, design) -> str | None:
    """A warning when the best candidate's task score did not beat the all-zero floor (None otherwise)."""
    from lfm_studio.engine.optimize import auto_crop

    names = record.get("at_floor") or []
    if not names:
        return None
    better = auto_crop(design)
    if crop is not None and (better is None or crop < better):
        fix = f"rerun with {_crop_fix(design)} (a crop that holds enough sub-images) and a new --study-name or database"
    else:
        fix = "more --photons or --iterations, or a design whose views reach the sensor"
    values = record.get("values") or {}
    scores = ", ".join(f"{n} {values[n]:.4g}" if n in values else n for n in names)
    return (
        f"warning: the best candidate's {scores} does not beat the all-zero volume's score by the margin: its "
        f"reconstruction holds almost nothing of the phantom, so the ranking (and the design written) is noise. "
        f"Fix: {fix}."
    )


def _sizes(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError as error:
        raise argparse.ArgumentTypeError(
            f"--sizes must be comma-separated integers (cells); got {text!r}"
        ) from error


def run_algorithm2(args: argparse.Namespace) -> int:
    """``optimize --algorithm2``: Algorithm 2 recorded into a resumable study; writes the best layout's design."""
    from lfm_studio.cli.simulate import _design_file
    from lfm_studio.engine.design import resolve_design, save_design
    from lfm_studio.engine.design.errors import DesignWarning
    from lfm_studio.engine.io import check_output
    from lfm_studio.engine.optimize import run_algorithm2_study
    from lfm_studio.engine.optimize.algorithm2_study import layout_key

    if args.space is not None:
        raise ValueError(
            f"--space {args.space} does not apply to --algorithm2 (it searches the MLA layout). Fix: drop --space."
        )
    if args.min_lenslet_um is None:
        raise ValueError(
            "--algorithm2 needs --min-lenslet-um (the cell size, um). Fix: e.g. --min-lenslet-um 2000."
        )
    out = check_output(
        args.out, overwrite=args.overwrite, inputs=[_design_file(args.design), _study_file(args.study)]
    )
    objectives = _objectives(args)
    if len(objectives) != 1:
        raise ValueError(
            f"--algorithm2 optimises one objective (a greedy search); got --objective {args.objective!r}. "
            "Fix: name one objective."
        )
    design = resolve_design(args.design)
    with progress_bar("optimise (algorithm 2)") as progress:
        result, study = run_algorithm2_study(
            design, objectives[0], args.study, min_lenslet_um=args.min_lenslet_um, symmetry=args.symmetry,
            sizes=args.sizes, study_name=args.study_name, resume=args.resume, settings=_settings(args, design),
            seed=args.seed, progress=progress,
        )  # fmt: skip
    print(f"{len(study.trials)} layouts stored; this run considered {result.counts_text()}")
    if result.design is None:
        raise ValueError(
            "no layout was feasible, nothing to write (see 'lfm-studio study show' for the reasons). "
            "Fix: a smaller --min-lenslet-um or relax the constraints."
        )
    objective = objectives[0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DesignWarning)
        chosen = result.design.updated(
            name=f"{design.name} (Algorithm 2)",
            description=f"{design.description} Optimised by lfm-studio optimize --algorithm2: study "
            f"{args.study_name!r} in {args.study}, {objective.name} = {result.score:.6g} {objective.unit}, "
            f"layout {layout_key(result.blocks)} (cells of {args.min_lenslet_um:g} um).".strip(),
        )
        save_design(chosen, out, overwrite=args.overwrite)
    for note in dict.fromkeys(str(w.message) for w in caught):
        print(f"design warning: {note}", file=sys.stderr)
    print(
        f"best layout: {len(result.blocks)} lenslets, {objective.name} = {result.score:.6g} {objective.unit}"
    )
    print(f"wrote {out}")
    return 0


def measured_before_update(result: Any) -> bool:
    """True when ``result.final_value`` (a :class:`~lfm_studio.engine.optimize.GradientResult`) is the
    last step's training loss at its point before the update (end to end), not a value of the final design."""
    return result.final_value_at == "before_last_update"


def _start_final_line(result: Any, objective: str, unit_text: str) -> str:
    """The start and final objective, saying where the final one was measured (``unit_text``: " um" or "")."""
    if not measured_before_update(result):
        return f"{objective}: start {result.start_value:.6g}{unit_text}, final {result.final_value:.6g}{unit_text}"
    last = len(result.history) - 1
    return (
        f"{objective} (training batches): {result.start_value:.6g}{unit_text} at step 0, "
        f"{result.final_value:.6g}{unit_text} at step {last}, each measured before its step's update "
        "(not evaluated at the final design; the held-out task loss below is)"
    )


def _change_text(result: Any, objective: str, unit_text: str) -> str:
    """The start -> final change recorded in the written design's description: the objective at the
    final design, or end to end the held-out task loss (the training loss was not measured there)."""
    snapped = "" if result.snapped_value is None else " (snapped to the catalogue)"
    if measured_before_update(result):
        extra = result.extra
        final = extra.get("held_out_snapped", extra["held_out_final"])
        return f"held-out task loss {extra['held_out_start']:.6g} -> {final:.6g} at the final design{snapped}"
    final = result.final_value if result.snapped_value is None else result.snapped_value
    return f"{objective} {result.start_value:.6g} -> {final:.6g}{unit_text}{snapped}"


def run_gradient(args: argparse.Namespace) -> int:
    """``optimize --gradient psf|end-to-end``: gradient descent recorded into a study; writes the final design."""
    from lfm_studio.cli.simulate import _design_file
    from lfm_studio.engine.design import resolve_design, save_design
    from lfm_studio.engine.design.errors import DesignWarning
    from lfm_studio.engine.io import check_output
    from lfm_studio.engine.learned.data import TrainingDataSpec
    from lfm_studio.engine.optimize import FocalLengthCatalogue, load_space, optimize_end_to_end, optimize_psf
    from lfm_studio.engine.optimize.gradient import psf_objective
    from lfm_studio.engine.optimize.task_score import TASK_PHOTONS

    if args.algorithm2:
        raise ValueError("--gradient and --algorithm2 are two different searches. Fix: pick one.")
    if args.resume and args.gradient == "end-to-end":
        raise ValueError(
            "end-to-end runs are not resumable (the reconstruction weights are not stored). Fix: drop --resume "
            "and give a new --study-name."
        )
    if args.keep_last and args.gradient == "end-to-end":
        raise ValueError(
            "--keep-last is for --gradient psf (end to end always keeps the last point). Fix: drop it."
        )
    out = check_output(
        args.out,
        overwrite=args.overwrite,
        inputs=[_design_file(args.design), args.space, _study_file(args.study)],
    )
    design = resolve_design(args.design)
    space = load_space(args.space)
    common = {
        "steps": args.steps, "optimizer": args.optimizer, "lr": args.lr, "schedule": args.schedule,
        "dtype": "float64" if args.float64 else "float32", "settings": _settings(args, design),
        "constraints": _constraints(args, design),
        "catalogue": FocalLengthCatalogue(args.catalogue) if args.catalogue else None,
        "check_float64": not args.no_float64_check, "study": args.study, "study_name": args.study_name,
        "seed": args.seed,
    }  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DesignWarning)
        with progress_bar(f"optimise (gradient {args.gradient})") as progress:
            if args.gradient == "psf":
                objective = args.objective or "axial_crb"
                options = {"photons": args.photons, "background": args.background}
                refuse_unused(args, [psf_objective(objective, options)])
                result = optimize_psf(
                    design, space, objective, options=options, progress=progress, resume=args.resume,
                    final="last" if args.keep_last else "best", **common,
                )  # fmt: skip
                unit = result.study.user_attrs["objectives"][0]["unit"]
            else:
                if args.objective:
                    raise ValueError(
                        "--gradient end-to-end optimises the task loss; --objective does not apply. Fix: drop it."
                    )
                objective, unit = "task_loss", ""
                if args.background is not None:
                    raise ValueError(
                        f"--background {args.background:g} does not apply to --gradient end-to-end "
                        f"({OPTION_USERS['background']}). Fix: drop --background."
                    )
                photons = TASK_PHOTONS if args.photons is None else args.photons
                data = TrainingDataSpec(
                    phantoms=args.phantom, objects=(4, 10), photons=(photons,), seed=args.seed
                )
                result = optimize_end_to_end(
                    design, space, reconstruction=args.reconstruction, freeze_optics=args.freeze_optics,
                    freeze_reconstruction=args.freeze_reconstruction, lr_reconstruction=args.lr_reconstruction,
                    iterations=args.unrolled_iterations, batch=args.batch, held_out=args.held_out, data=data,
                    progress=progress, **common,
                )  # fmt: skip
        unit_text = f" {unit}" if unit else ""  # no blank before a comma when unitless
        chosen = result.design.updated(
            name=f"{design.name} (gradient {args.gradient})",
            description=f"{design.description} Optimised by lfm-studio optimize --gradient {args.gradient}: study "
            f"{args.study_name!r} in {args.study}, {len(result.history)} {args.optimizer} steps, "
            f"{_change_text(result, objective, unit_text)}.".strip(),
        )
        save_design(chosen, out, overwrite=args.overwrite)
    for note in dict.fromkeys([*result.warnings, *(str(w.message) for w in caught)]):
        print(f"design warning: {note}", file=sys.stderr)
    for step in result.history:
        point = ", ".join(f"{k}={v:.6g}" for k, v in step.point.items())
        note = f"  (update backtracked: {step.infeasible.split(':')[0]})" if step.infeasible else ""
        print(
            f"step {step.step:3d}  {objective} {step.value:.6g}{unit_text}  |grad| {step.grad_norm:.3g}  {point}{note}"
        )
    print(_start_final_line(result, objective, unit_text))
    if result.resumed_from:
        print(
            f"resumed: {result.resumed_from} stored steps, the optimiser restarted from the stored {result.final} point"
        )
    if result.best is not None:
        batches = " (training batch)" if measured_before_update(result) else ""
        print(f"best step {result.best.step}: {objective}{batches} {result.best.value:.6g}{unit_text}")
    if result.last_value is not None:
        print(f"last point (after the last update): {objective} {result.last_value:.6g}{unit_text}")
    if args.gradient == "psf":
        print(
            f"the design written is the {result.final} point: {objective} {result.final_value:.6g}{unit_text}"
        )
    if args.gradient == "end-to-end":
        extra = result.extra
        where = "the final design" if result.snapped_value is None else "the final point (before snapping)"
        print(
            f"held-out task loss: start {extra['held_out_start']:.6g}, final {extra['held_out_final']:.6g} at "
            f"{where} (all-zero volume: {extra['zero_floor']:.6g}); final volume "
            f"{extra['final_volume_trivial'] or 'not trivial'}"
        )
    if result.snapped_value is not None:
        what = "held-out task loss" if args.gradient == "end-to-end" else objective
        before = result.extra.get("held_out_final", result.final_value)
        print(
            f"snapped to the catalogue: {what} {before:.6g} -> {result.snapped_value:.6g}{unit_text} "
            "(the design written)"
        )
    if result.check is not None:
        verdict = "within" if result.check.passed else "OUTSIDE"
        print(
            f"float32 vs float64 start gradient: relative difference {result.check.relative_error:.3g} "
            f"({verdict} the tolerance {result.check.tolerance:g})"
        )
    print(f"wrote {out}")
    return 0


def _study_kept(args: argparse.Namespace) -> str | None:
    """What an interrupted ``optimize`` kept in its study (finished trials) and how to continue;
    None when the study holds none (or does not exist: it is not created here)."""
    from lfm_studio.engine.optimize.study import load_study
    from lfm_studio.engine.optimize.study_report import summary

    database = _study_file(args.study)
    if database is not None and not Path(database).expanduser().is_file():
        return None
    counts = summary(load_study(args.study, args.study_name))
    finished = counts.get("complete", 0) + counts.get("infeasible", 0)
    if not finished:
        return None
    how = (
        "Fix: an end-to-end run is not resumable; run it again with another --study-name."
        if args.gradient == "end-to-end"
        else "Fix: run the same command with --resume to continue (no stored candidate is evaluated again)."
    )
    return (
        f"the study {args.study_name!r} in {args.study} keeps its {finished} finished trial(s) "
        f"('lfm-studio study show' lists them); --out {args.out} was not written. {how}"
    )


def run_optimize(args: argparse.Namespace) -> int:
    """Handler of ``optimize``; a Ctrl+C says whether --out was written, else what the study kept."""
    with on_interrupt(lambda: _study_kept(args)):
        return _run_optimize(args)


@watching("out")
def _run_optimize(args: argparse.Namespace) -> int:
    if args.gradient is not None:
        return run_gradient(args)
    if args.objective is None:
        raise ValueError(
            "optimize needs --objective NAME. Fix: e.g. --objective task_ncc (docs/optimize.md)."
        )
    if args.algorithm2:
        return run_algorithm2(args)
    if args.space is None:
        raise ValueError("optimize needs --space space.json (or --algorithm2). Fix: see docs/optimize.md.")
    from lfm_studio.cli.simulate import _design_file
    from lfm_studio.engine.design import resolve_design, save_design
    from lfm_studio.engine.design.design_io import design_from_json
    from lfm_studio.engine.io import check_output
    from lfm_studio.engine.optimize import Evaluator, FocalLengthCatalogue, load_space
    from lfm_studio.engine.optimize.study import record_of, run_study
    from lfm_studio.engine.optimize.study_report import (
        format_front,
        insensitive_parameters,
        pareto_front,
        summary,
    )

    out = check_output(
        args.out,
        overwrite=args.overwrite,
        inputs=[_design_file(args.design), args.space, _study_file(args.study)],
    )
    if args.workers < 1:
        raise ValueError(f"--workers must be >= 1; got {args.workers}.")
    design = resolve_design(args.design)
    space = load_space(args.space)
    settings = _settings(args, design)
    evaluator = Evaluator(
        design,
        space,
        _objectives(args),
        constraints=_constraints(args, design),
        catalogue=FocalLengthCatalogue(args.catalogue) if args.catalogue else None,
        settings=settings,
        seed=args.seed,
    )
    with _client(args) as client, progress_bar(f"optimise ({args.sampler})") as progress:
        study = run_study(
            evaluator, args.study, study_name=args.study_name, sampler=args.sampler, n_trials=args.trials,
            resume=args.resume, client=client, progress=progress,
        )  # fmt: skip
    counts = summary(study)
    print(", ".join(f"{k} {v}" for k, v in counts.items()))
    print(format_front(study))
    front = pareto_front(study)
    if not front:
        raise ValueError(
            "no candidate was feasible, nothing to write (see 'lfm-studio study show' for the reasons). "
            "Fix: widen the space or relax the constraints."
        )
    for found in insensitive_parameters(study):
        print(_insensitive_note(found, design), file=sys.stderr)
    best = _best(front, evaluator.objectives)
    chosen = design_from_json(record_of(best)["design_json"], origin=f"study trial {best.number}")
    chosen = chosen.updated(
        name=f"{design.name} (optimised, trial {best.number})",
        description=f"{design.description} Optimised by lfm-studio optimize: study {args.study_name!r} in "
        f"{args.study}, trial {best.number}, objectives {[o.name for o in evaluator.objectives]}, "
        f"values {list(best.values)}, parameters {best.params}.".strip(),
    )
    save_design(chosen, out, overwrite=args.overwrite)
    print(f"best design (trial {best.number}): {', '.join(f'{k}={v}' for k, v in best.params.items())}")
    print(f"wrote {out}")
    floor = _floor_warning(record_of(best), settings.crop, design)
    if floor is not None:
        print(floor, file=sys.stderr)
    return 0


def _insensitive_note(found, design) -> str:
    """The note for a parameter that changed no value of an objective (:func:`insensitive_parameters`)."""
    from lfm_studio.engine.systems.kinds import kind_of

    note = (
        f"note: {found.parameter} did not change {found.objective} in "
        + ("the one group" if found.groups == 1 else f"any of the {found.groups} groups")
        + f" of candidates that differ only in it (e.g. {found.value:.6g}): in this space the objective does not see it."
    )
    if found.parameter == "objective.numerical_aperture" and kind_of(design).mla_at_pupil:
        note += (
            " On this design the lenslet apertures, which the default constraints keep inside the relayed pupil, "
            "stop the light, not the objective's NA: the PSF is the same for every NA whose pupil holds them all."
        )
    return note


def _best(front: list, objectives) -> object:
    """The front's best candidate on the first objective (the whole front is printed)."""
    first = objectives[0]
    key = (lambda t: t.values[0]) if first.direction == "minimize" else (lambda t: -t.values[0])
    return min(front, key=key)


def run_study_show(args: argparse.Namespace) -> int:
    from lfm_studio.engine.optimize.study import load_study
    from lfm_studio.engine.optimize.study_report import format_front, format_table, summary

    study = load_study(args.study, args.study_name)
    print(f"study {study.study_name!r}: {', '.join(f'{k} {v}' for k, v in summary(study).items())}")
    print(format_table(study, limit=args.limit))
    print(format_front(study))
    return 0


def add_optimize_parsers(sub: argparse._SubParsersAction) -> None:
    """Register ``optimize`` and ``study`` (``study show``)."""
    from lfm_studio.cli.simulate import allow_negative_values

    opt = allow_negative_values(
        sub.add_parser(
            "optimize",
            help="search a design space (stored, resumable study) and write the best design",
            description=__doc__,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
    )
    opt.add_argument("design", help="starting design file (.json) or preset name")
    opt.add_argument(
        "--space", default=None, help="design space JSON (docs/optimize.md); not with --algorithm2"
    )
    opt.add_argument(
        "--objective",
        default=None,
        help="objective name, or several comma-separated (a Pareto front); required except with "
        "--gradient (psf: default axial_crb; end-to-end: the task loss)",
    )
    opt.add_argument(
        "--study", default=DEFAULT_STUDY, help=f"study database URL or file (default {DEFAULT_STUDY})"
    )
    opt.add_argument("--study-name", default="lfm_study", help="study name inside the database")
    opt.add_argument(
        "--resume", action="store_true", help="continue a stored study (no candidate is evaluated twice)"
    )
    opt.add_argument("--sampler", choices=("grid", "tpe", "cmaes", "random"), default="grid")
    opt.add_argument("--trials", type=int, default=None, help="total trials (default: the whole grid, or 20)")
    opt.add_argument("--workers", type=int, default=1, help="evaluate on a local Dask cluster of N processes")
    opt.add_argument(
        "--scheduler", default=None, help="Dask scheduler address (a cluster) instead of --workers"
    )
    opt.add_argument("--seed", type=int, default=0, help="sampler seed (recorded with every trial)")
    opt.add_argument(
        "--crop",
        type=int,
        default=None,
        help="camera pixels simulated about the axis (default: automatic, the smallest from 256 px in "
        "128 px steps that holds the sub-image centres of 3 lenslets, e.g. 512 for xlfm_cong2017; "
        "with --resume, the stored study's)",
    )
    opt.add_argument("--depths", type=str, default=None, help="START:STOP:STEP in um (default: the design's)")
    opt.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    task = opt.add_argument_group("task score (task_* objectives)")
    task.add_argument("--phantom", choices=("beads", "cells"), default="beads")
    task.add_argument(
        "--method", default="rl", help="reconstruction method (rl, rl-accelerated, wiener, tikhonov)"
    )
    task.add_argument("--iterations", type=int, default=20)
    task.add_argument(
        "--photons",
        type=float,
        default=None,
        help="photons: for axial_crb detected per emitter (default 1000), for task_* objectives and "
        "--gradient end-to-end expected per image (default 1e5)",
    )
    task.add_argument("--task-seeds", type=_seeds, default=(1000, 1001), help="held-out phantom seeds")
    alg2 = opt.add_argument_group("Algorithm 2 (MLA layout search; cells of --min-lenslet-um)")
    alg2.add_argument("--algorithm2", action="store_true", help="run Algorithm 2 instead of a space search")
    alg2.add_argument(
        "--symmetry",
        default="none",
        help="none, mirror, mirror-xy, 4-fold or 8-fold: every merge applies to the block's symmetric images",
    )
    alg2.add_argument("--sizes", type=_sizes, default=None, help="block sizes to try, cells (default 1..M-1)")
    grad = opt.add_argument_group("gradient optimisation (Fourier or conventional LFM; docs/optimize.md)")
    grad.add_argument(
        "--gradient", choices=("psf", "end-to-end"), default=None, help="gradient descent instead of a search"
    )
    grad.add_argument(
        "--steps",
        type=int,
        default=20,
        help="gradient steps (one study trial each; with --resume, the total)",
    )
    grad.add_argument(
        "--keep-last",
        action="store_true",
        help="psf: write the point after the last update, not the best point evaluated",
    )
    grad.add_argument("--optimizer", choices=("adam", "lbfgs"), default="adam")
    grad.add_argument(
        "--lr", type=float, default=0.05, help="optics step, fraction of each parameter's range"
    )
    grad.add_argument("--schedule", choices=("constant", "cosine", "exponential", "step"), default="constant")
    grad.add_argument("--float64", action="store_true", help="run in float64 (default float32)")
    grad.add_argument(
        "--no-float64-check", action="store_true", help="skip the float32-float64 start-gradient check"
    )
    grad.add_argument(
        "--background",
        type=float,
        default=None,
        help="axial_crb background, photons per pixel (default 1; any search method); refused for other objectives",
    )
    grad.add_argument("--reconstruction", choices=("unrolled-rl", "rl"), default="unrolled-rl")
    grad.add_argument(
        "--freeze-optics", action="store_true", help="end-to-end: train the reconstruction only"
    )
    grad.add_argument(
        "--freeze-reconstruction", action="store_true", help="end-to-end: train the optics only"
    )
    grad.add_argument("--lr-reconstruction", type=float, default=0.01)
    grad.add_argument("--unrolled-iterations", type=int, default=4, help="unrolled RL steps")
    grad.add_argument("--batch", type=int, default=2, help="training phantoms per step")
    grad.add_argument("--held-out", type=int, default=4, help="held-out phantoms scored at the start and end")
    cons = opt.add_argument_group("constraints")
    cons.add_argument(
        "--catalogue", type=_floats, default=None, help="stock lenslet focal lengths in mm (snap)"
    )
    cons.add_argument(
        "--min-lenslet-um",
        type=float,
        default=None,
        help="smallest lenslet aperture, um (with --algorithm2: the cell size)",
    )
    cons.add_argument(
        "--require-zebrafish", action="store_true", help="refuse designs failing the zebrafish spec"
    )
    opt.add_argument("--out", required=True, help="best design file to write (.json)")
    opt.add_argument("--overwrite", "--force", action="store_true", help="replace an existing --out")
    opt.set_defaults(handler=run_optimize)

    study = sub.add_parser("study", help="inspect stored optimisation studies")
    actions = study.add_subparsers(dest="study_command", metavar="ACTION", required=True)
    show = actions.add_parser("show", help="print a study's trials and its best candidate / Pareto front")
    show.add_argument("study", help="study database file or URL")
    show.add_argument("--study-name", default=None, help="the study (default: the only one in the database)")
    show.add_argument("--limit", type=int, default=None, help="show only the last N trials")
    show.set_defaults(handler=run_study_show)


__all__ = ["add_optimize_parsers"]
