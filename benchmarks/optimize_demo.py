"""The demonstration that matters: optimise one objective, then check an independent, unoptimised metric.

    PYTHONPATH=. python benchmarks/optimize_demo.py [--case xlfm lfm] [--objective axial_crb]
        [--crop 256] [--depths 5] [--check-seeds 8] [--iterations 20] [--photons 1e5] [--threads 1]

Two starting designs, each searched on a stored SQLite study (grid sampler, :func:`run_study`):

- ``xlfm``: the shipped XLFM (``xlfm_cong2017``); the focal length of the second lenslet
  group (12 lenslets tied; hand design 28.5 mm) over ``--xlfm-focals``;
- ``lfm``: the conventional ``lfm_10x_na03`` (regular square MLA, 125 um pitch); the MLA
  focal length over ``--lfm-focals`` (hand design 1.875 mm), or with ``--lfm-parameter
  pitch`` the MLA pitch over ``--lfm-pitches`` (hand 125 um; the lenslet count is kept), or
  with ``focal-refocused`` the focal length with the camera moved to the lenslets' back
  focal plane (``mla_to_camera_distance_mm`` = f, as in the hand design); with ``spherical``
  a rotationally symmetric phase mask on the objective's back focal plane (Cohen et al. 2014's
  wavefront coding, restricted to what the radial Debye model carries): the Noll 11 (primary
  spherical) coefficient over ``--lfm-mask-waves`` (hand design: no mask, 0 waves), or with
  ``defocus-mask`` the Noll 4 (defocus) coefficient over the same values.

Every candidate must keep the closed-form field of view and depth of field at least the
hand design's (:class:`NoWorseFieldAndDepth`, plus the default checks). Cropped so one run
fits in minutes on two CPU cores: a ``--crop`` px sensor crop about the axis and ``--depths``
depths over +-40 um.

The optimised objective (default ``axial_crb``: the mean axial Cramer-Rao bound of a point
emitter, ``--crb-photons`` photons and 1 background photon per pixel, thesis 5.2.2) is computed
on the PSF only; a ``task_*`` objective uses phantoms with seeds 1000 and 1001 at ``--photons``. The independent check is a task nobody optimised: bead phantoms with seeds
``3000 ...`` (disjoint from the task score's 1000-series and from any seed used while
optimising), imaged at the same ``--photons`` budget for both designs, reconstructed with
plain RL, scored with bead F1 and localisation error (um). Each seed is scored on its own
and the table gives mean +- standard deviation over the seeds.
"""

from __future__ import annotations

import lfm_studio  # noqa: F401  # isort: skip  (first: sets OMP_WAIT_POLICY before torch loads)
import argparse
import statistics
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import torch

from lfm_studio.engine.design import Design, load_preset
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.image_quality import peak_match
from lfm_studio.engine.optimize import (
    DEFAULT_CONSTRAINTS,
    Candidate,
    DesignSpace,
    EvaluationSettings,
    Evaluator,
    Infeasible,
    Parameter,
    TaskScore,
    objective_named,
)
from lfm_studio.engine.optimize.study import record_of, run_study
from lfm_studio.engine.performance import closed_form_metrics
from lfm_studio.engine.threads import describe_threads

CHECK_SEED0 = 3000  # held-out check phantoms: disjoint from the task score's seeds
TASK_SEEDS = (1000, 1001)  # phantoms of a task_* objective while optimising
MASK_TERMS = {"spherical": 11, "defocus-mask": 4}  # --lfm-parameter: Noll index of the pupil mask


@dataclass(frozen=True)
class NoWorseFieldAndDepth:
    """Constraint: closed-form field of view and depth of field at least ``fov_um`` / ``dof_um``."""

    fov_um: float
    dof_um: float
    name: str = "no_worse_fov_dof"

    def check(self, design: Design) -> Infeasible | None:
        m = closed_form_metrics(design)
        fov, dof = m.field_of_view * 1e6, m.depth_of_field * 1e6
        if fov < self.fov_um - 1e-6 or dof < self.dof_um - 1e-6:
            return Infeasible(
                "requirement_failed",
                f"FoV {fov:.4g} um / DoF {dof:.4g} um below the hand design's {self.fov_um:.4g} / {self.dof_um:.4g} um",
            )
        return None


@dataclass(frozen=True)
class RefocusedMLASpace(DesignSpace):
    """A space over the MLA focal length that keeps the camera in the lenslets' back focal plane
    (``mla_to_camera_distance_mm`` = the focal length, as in the hand design)."""

    def apply(self, design: Design, point) -> Design:
        moved = super().apply(design, point)
        return moved.updated(mla_to_camera_distance_mm=moved.mla.focal_length_mm)


def with_depths(name: str, depths: int) -> Design:
    """Preset ``name`` with ``depths`` depths over +-40 um."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        base = load_preset(name)
        step = 80.0 / max(depths - 1, 1)
        return base.updated(depths={"depth_range_um": (-40.0, 40.0), "depth_step_um": step})


def case(name: str, args: argparse.Namespace) -> tuple[Design, DesignSpace, float]:
    """``(base design, space, hand value of the parameter)`` of a demonstration case."""
    if name == "xlfm":
        base = with_depths("xlfm_cong2017", args.depths)
        second = ",".join(str(i) for i, lens in enumerate(base.mla.lenslets) if lens.focal_length_mm != 26.0)
        path = f"mla.lenslets[{second}].focal_length_mm"  # the whole second group moves together
        return base, DesignSpace((Parameter(path, choices=tuple(args.xlfm_focals)),)), 28.5
    base = with_depths("lfm_10x_na03", args.depths)
    if args.lfm_parameter in MASK_TERMS:  # the term listed at 0 waves: the hand design's PSF, bit for bit
        noll = MASK_TERMS[args.lfm_parameter]
        base = base.updated(pupil_phase={"zernike_waves": {str(noll): 0.0}})
        path = f"pupil_phase.zernike_waves.{noll}"
        return base, DesignSpace((Parameter(path, choices=tuple(args.lfm_mask_waves)),)), 0.0
    if args.lfm_parameter == "pitch":
        space = DesignSpace((Parameter("mla.pitch_um", choices=tuple(args.lfm_pitches)),))
        return base, space, base.mla.pitch_um
    hand = base.mla.focal_length_mm
    kind = RefocusedMLASpace if args.lfm_parameter == "focal-refocused" else DesignSpace
    return base, kind((Parameter("mla.focal_length_mm", choices=tuple(args.lfm_focals)),)), hand


def check(
    design: Design, settings: EvaluationSettings, args: argparse.Namespace
) -> tuple[dict[str, list[float]], dict[int, list[int]]]:
    """Bead F1 and localisation error (um) per held-out seed (one reconstruction per seed, shared),
    and per depth index ``[beads, matched]`` pooled over the seeds (where the beads are lost)."""
    candidate = Candidate(design, settings)
    out: dict[str, list[float]] = {"f1": [], "localisation": []}
    by_depth: dict[int, list[int]] = {}
    for seed in range(CHECK_SEED0, CHECK_SEED0 + args.check_seeds):
        for metric in out:
            task = TaskScore(metric, iterations=args.iterations, photons=args.photons, seeds=(seed,))
            out[metric].append(task(candidate))
        truth, estimate, reference = task.trial(candidate, seed)  # the memoised reconstruction
        match = peak_match(truth, estimate, reference=reference, voxel_size=candidate.setup.voxel_size,
                           tolerance=task.tolerance)  # fmt: skip
        found = set(match.pairs[:, 1].tolist())
        for i, z in enumerate(reference[:, 0].tolist()):
            counts = by_depth.setdefault(int(z), [0, 0])
            counts[0] += 1
            counts[1] += int(i in found)
    return out, dict(sorted(by_depth.items()))


def spread(values: list[float]) -> str:
    finite = [v for v in values if v == v and abs(v) != float("inf")]
    if not finite:
        return "undefined"
    sd = statistics.stdev(finite) if len(finite) > 1 else 0.0
    note = "" if len(finite) == len(values) else f" ({len(values) - len(finite)} undefined)"
    return f"{statistics.fmean(finite):.3f} +- {sd:.3f}{note}"


def run_case(name: str, args: argparse.Namespace, folder: Path) -> None:
    base, space, hand_value = case(name, args)
    (parameter,) = space.parameters
    hand = closed_form_metrics(base)
    keep = NoWorseFieldAndDepth(hand.field_of_view * 1e6, hand.depth_of_field * 1e6)
    constraints = (*DEFAULT_CONSTRAINTS, keep) if base.kind == "fourier" else (keep,)
    settings = EvaluationSettings(crop=args.crop)
    if args.objective.startswith("task_"):  # the task score's own seeds, disjoint from the check's
        options = {"photons": args.photons, "iterations": args.iterations, "seeds": TASK_SEEDS}
    else:
        options = {"photons": args.crb_photons}
    objective = objective_named(args.objective, options)
    evaluator = Evaluator(base, space, [objective], constraints=constraints, settings=settings)
    print(
        f"\n== {name}: {base.name}; {parameter.path} in {list(parameter.grid())} (hand {hand_value}); "
        f"objective {objective.name} [{objective.unit or '-'}] ({objective.direction}); {args.crop} px crop, "
        f"{args.depths} depths over +-40 um; FoV >= {keep.fov_um:.4g} um, DoF >= {keep.dof_um:.4g} um"
    )
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        study = run_study(evaluator, f"sqlite:///{folder / f'{name}.db'}")
    print(f"study: {len(study.trials)} trials in {time.perf_counter() - start:.1f} s")
    rows = sorted(study.trials, key=lambda t: t.params[parameter.path])
    label = parameter.path.split(".")[-1]
    label = f"Noll {label} (waves)" if label.isdigit() else label
    for t in rows:
        record = record_of(t)
        value = (
            f"{t.values[0]:.5g}"
            if t.state.name == "COMPLETE"
            else f"infeasible ({record['infeasible_reason']}: {record['infeasible_message']})"
        )
        print(f"  {label} {t.params[parameter.path]:g}: {objective.name} {value}")
    complete = [t for t in rows if t.state.name == "COMPLETE"]
    hand_trial = next((t for t in complete if abs(t.params[parameter.path] - hand_value) < 1e-9), None)
    if not complete or hand_trial is None:
        print("  the hand design was not scored (infeasible?): nothing to compare")
        return
    pick = min if objective.direction == "minimize" else max
    best = pick(complete, key=lambda t: t.values[0])
    print(
        f"optimised: {best.params[parameter.path]:g} ({objective.name} {best.values[0]:.5g}) vs hand "
        f"{hand_value:g} ({hand_trial.values[0]:.5g})"
    )
    seeds = f"seeds {CHECK_SEED0}-{CHECK_SEED0 + args.check_seeds - 1}"
    print(
        f"independent check ({seeds}, {args.photons:g} photons, RL {args.iterations} it), mean +- sd over seeds:"
    )
    found = {}
    for label, trial in (("hand", hand_trial), ("optimised", best)):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DesignWarning)
            design = space.apply(base, trial.params)
            scores, by_depth = check(design, settings, args)
            found[label] = scores
        m = closed_form_metrics(design)
        print(
            f"  {label:9s} {trial.params[parameter.path]:6g}: bead F1 {spread(scores['f1'])}, localisation "
            f"{spread(scores['localisation'])} um; FoV {m.field_of_view * 1e6:.0f} um, DoF {m.depth_of_field * 1e6:.1f} um"
        )
        depths_um = list(design.depths.values_um)
        print(
            "            beads matched per depth (all seeds): "
            + ", ".join(f"{depths_um[z]:+.0f} um {n_ok}/{n}" for z, (n, n_ok) in by_depth.items())
        )
    for metric, better in (("f1", 1.0), ("localisation", -1.0)):  # paired: the same phantoms for both designs
        deltas = [o - h for o, h in zip(found["optimised"][metric], found["hand"][metric], strict=True)]
        wins = sum(1 for d in deltas if better * d > 1e-12)
        losses = sum(1 for d in deltas if better * d < -1e-12)
        print(
            f"  paired optimised - hand, {metric}: {spread(deltas)}; better on {wins}, worse on {losses} "
            f"of {len(deltas)} phantoms"
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--case", nargs="+", choices=("xlfm", "lfm"), default=["xlfm", "lfm"])
    parser.add_argument("--objective", default="axial_crb", help="a registered objective (docs/optimize.md)")
    parser.add_argument("--crb-photons", type=float, default=1000.0, help="photons per emitter (axial_crb)")
    parser.add_argument("--crop", type=int, default=256)
    parser.add_argument("--depths", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--photons", type=float, default=1e5, help="photons per image of the check")
    parser.add_argument("--check-seeds", type=int, default=8)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--xlfm-focals", type=float, nargs="+", default=[27.0, 27.5, 28.0, 28.5, 29.0, 29.5, 30.0]
    )
    parser.add_argument(
        "--lfm-parameter",
        choices=("focal", "focal-refocused", "pitch", *MASK_TERMS),
        default="focal",
        help="the conventional field searched (focal-refocused: the camera follows the focal plane; "
        "spherical / defocus-mask: Noll 11 / 4 of a back-focal-plane phase mask)",
    )
    parser.add_argument(
        "--lfm-mask-waves", type=float, nargs="+", default=[-0.6, -0.4, -0.2, 0.0, 0.2, 0.4, 0.6]
    )
    parser.add_argument("--lfm-focals", type=float, nargs="+", default=[1.5, 1.875, 2.25, 2.625])
    parser.add_argument("--lfm-pitches", type=float, nargs="+", default=[100.0, 112.5, 125.0, 137.5, 150.0])
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(describe_threads())
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.case:
            run_case(name, args, Path(tmp))


if __name__ == "__main__":
    main()
