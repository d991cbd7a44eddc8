"""Task score (objective kind c): held-out phantoms imaged through a candidate and reconstructed.

For each held-out seed: a seeded phantom (beads or cell-like spheres) on the candidate's
volume grid, its light-field image at a photon budget with the design's camera (shot and
read noise; :func:`~lfm_studio.engine.simulation.light_field_image`), converted back to
photons, reconstructed with a named method (:func:`~lfm_studio.engine.reconstruct.reconstruct_frame`),
then scored with a metric a trivial volume cannot pass (:func:`score_volume`):

- ``ncc``: Pearson correlation with the truth (unitless, maximise; the all-zero volume scores 0);
- ``f1``: bead detection F1 against the phantom's own object positions (unitless, maximise;
  the all-zero volume scores 0);
- ``localisation``: the OSPA distance (Schuhmacher, Vo and Vo 2008, order 1, cut-off ``c`` = the
  match tolerance): ``(sum of matched distances + c x (max(found, true) - matched)) / max(found,
  true)``, so a missed object and a false peak each cost ``c`` (um, minimise; the all-zero
  volume scores ``c``, the worst value, and so does a noise volume with many false peaks). The
  mean over the true objects alone, used before stop 28, let a noisy reconstruction whose
  spurious peaks lay near every bead score 3.4 um against 5.2 um for a clean one (F1 0.016).

The score is the mean over the seeds. Seeds default to 1000 and up, apart from the seeds
small examples and tests use for anything they tune (0, 1, 2...).

Every score is compared with the all-zero volume's score on the same phantoms (the floor,
:meth:`TaskScore.floor`); a score that does not beat it by ``margin`` of the way from the floor to
a perfect score warns :class:`TaskFloorWarning` (the :class:`~.evaluate.Evaluator` records the
candidate's objective in ``at_floor``): such a reconstruction holds almost nothing of the phantom
and ranking candidates on it ranks noise. Measured: ``xlfm_cong2017`` on a 256 px sensor crop,
which holds none of its sub-image centres, scores ``task_ncc`` 0.008-0.05 (:mod:`.crop`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch

from lfm_studio.engine.image_quality import ncc, peak_match
from lfm_studio.engine.io.camera_counts import counts_to_photons, design_camera
from lfm_studio.engine.optimize.candidate import Candidate
from lfm_studio.engine.optimize.objectives import Direction, Objective, ObjectiveFactory, register_objective
from lfm_studio.engine.reconstruct import reconstruct_frame, registry
from lfm_studio.engine.simulation import camera_of, light_field_image, make_phantom

TASK_METRICS: dict[str, tuple[str, Direction]] = {
    "ncc": ("", "maximize"),
    "f1": ("", "maximize"),
    "localisation": ("um", "minimize"),
}
"""Task metrics: name -> (unit, direction)."""

PERFECT_SCORES: dict[str, float] = {"ncc": 1.0, "f1": 1.0, "localisation": 0.0}
"""The best value each task metric can take (a reconstruction equal to the truth)."""

HELD_OUT_SEEDS: tuple[int, ...] = (1000, 1001)

TASK_PHOTONS = 1e5
"""Default expected photons reaching the camera per image of a held-out phantom (all its objects
together; compare :data:`.objectives.CRB_PHOTONS`, per emitter)."""

FLOOR_MARGIN = 0.05
"""Default :attr:`TaskScore.margin`: a score must get 5 % of the way from the all-zero floor to a
perfect score (``task_ncc`` above 0.05) to count as beating the floor."""


class TaskFloorWarning(UserWarning):
    """A task score that does not beat the all-zero volume's score by the margin.

    ``objective``: the objective's name; ``value``, ``floor``, ``threshold``: the score, the
    all-zero volume's score and the value it had to beat, in the objective's unit.
    """

    def __init__(self, message: str, *, objective: str, value: float, floor: float, threshold: float) -> None:
        super().__init__(message)
        self.objective, self.value, self.floor, self.threshold = objective, value, floor, threshold


def score_volume(
    metric: str,
    truth: torch.Tensor,
    estimate: torch.Tensor,
    *,
    reference: torch.Tensor | None = None,
    voxel_size: tuple[float, float, float] | None = None,
    tolerance: float = 2.0,
) -> float:
    """``metric`` (see :data:`TASK_METRICS`) of ``estimate`` against ``truth`` ``(Z, Y, X)``.

    ``reference``: ``(N, 3)`` voxel indices of the true objects (default: the truth's peaks);
    ``tolerance``: match distance in voxels; ``voxel_size`` ``(dz, dy, dx)`` m puts the
    localisation error in um (else voxels).
    """
    if metric not in TASK_METRICS:
        raise ValueError(f"task metric must be one of {sorted(TASK_METRICS)}; got {metric!r}.")
    if metric == "ncc":
        return float(ncc(truth, estimate))
    match = peak_match(truth, estimate, reference=reference, voxel_size=voxel_size, tolerance=tolerance)
    if metric == "f1":
        return match.f1
    # Worst pair distance a match can have, in the errors' unit: the tolerance along the coarsest axis.
    worst = tolerance * (max(voxel_size) * 1e6 if voxel_size is not None else 1.0)
    # OSPA (module docstring): every unpaired peak or object costs `worst`.
    size = max(match.found, match.reference)
    if size == 0:
        return 0.0
    total = float(match.errors.clamp_max(worst).sum()) + worst * (size - match.matched)
    return total / size


@dataclass(frozen=True)
class TaskScore:
    """Objective (c): mean ``metric`` over held-out phantoms imaged at ``photons`` and reconstructed.

    Attributes
    ----------
    metric : "ncc", "f1" or "localisation" (:data:`TASK_METRICS`).
    phantom : "beads" or "cells".
    method : reconstruction method (``reconstruct_frame``: rl, rl-accelerated, wiener, tikhonov).
    iterations : Richardson-Lucy iterations.
    photons : expected photons reaching the camera per image.
    seeds : held-out phantom (and noise) seeds.
    count : beads per phantom (None: the default that fits).
    tolerance : peak match distance in voxels (F1, localisation).
    margin : fraction of the way from the all-zero floor to a perfect score (:data:`PERFECT_SCORES`)
        a score must get to count as beating the floor; below it :meth:`__call__` warns
        :class:`TaskFloorWarning` (the score is still returned). 0 warns only at or below the floor.
    """

    metric: str = "ncc"
    phantom: str = "beads"
    method: str = "rl"
    iterations: int = 20
    photons: float = TASK_PHOTONS
    seeds: tuple[int, ...] = HELD_OUT_SEEDS
    count: int | None = None
    tolerance: float = 2.0
    margin: float = FLOOR_MARGIN

    def __post_init__(self) -> None:
        if self.metric not in TASK_METRICS:
            raise ValueError(f"task metric must be one of {sorted(TASK_METRICS)}; got {self.metric!r}.")
        if self.method not in registry.names():
            raise ValueError(f"task method must be one of {registry.names()}; got {self.method!r}.")
        if self.phantom not in ("beads", "cells"):
            raise ValueError(f"task phantom must be 'beads' or 'cells'; got {self.phantom!r}.")
        if not (math.isfinite(self.photons) and self.photons > 0):
            raise ValueError(f"photons must be > 0 (expected photons per image); got {self.photons!r}.")
        if not self.seeds:
            raise ValueError("seeds is empty. Fix: give at least one held-out seed, e.g. (1000,).")
        if not (math.isfinite(self.margin) and 0.0 <= self.margin < 1.0):
            raise ValueError(
                f"margin must lie in [0, 1) (a fraction of the way from the all-zero floor to a perfect "
                f"score); got {self.margin!r}. Fix: e.g. {FLOOR_MARGIN}."
            )

    @property
    def name(self) -> str:
        return f"task_{self.metric}"

    @property
    def unit(self) -> str:
        return TASK_METRICS[self.metric][0]

    @property
    def direction(self) -> Direction:
        return TASK_METRICS[self.metric][1]

    def score_options(self) -> dict[str, Any]:
        """What changes the score (stored with a study; ``margin`` only changes the floor warning)."""
        return {
            "phantom": self.phantom, "method": self.method, "iterations": self.iterations,
            "photons": self.photons, "seeds": list(self.seeds), "count": self.count, "tolerance": self.tolerance,
        }  # fmt: skip

    def trial(self, candidate: Candidate, seed: int) -> tuple[torch.Tensor, torch.Tensor, Any]:
        """``(truth, reconstruction, object indices)`` for one seed (shared by the task metrics)."""
        key = ("task", self.phantom, self.method, self.iterations, self.photons, self.count, seed)
        if key not in candidate.memo:
            setup = candidate.setup
            with candidate.timed("simulate_s"):
                truth, _info = make_phantom(self.phantom, setup, seed=seed, count=self.count)
                counts, _ = light_field_image(
                    setup, truth, camera_of(candidate.design), photons=self.photons, seed=seed
                )
                calibration = design_camera(candidate.design.camera, "design camera")
                photons, background = counts_to_photons(counts, calibration, name="simulated image")
            with candidate.timed("reconstruct_s"):
                estimate = reconstruct_frame(
                    setup.projector,
                    photons,
                    method=self.method,
                    iterations=self.iterations,
                    background=background,
                )
            reference = _object_indices(truth) if self.phantom == "beads" else None
            candidate.memo[key] = (truth, estimate, reference)
        return candidate.memo[key]  # type: ignore[return-value]

    def _score(self, candidate: Candidate, seed: int, zero: bool) -> float:
        truth, estimate, reference = self.trial(candidate, seed)
        return score_volume(
            self.metric,
            truth,
            torch.zeros_like(estimate) if zero else estimate,
            reference=reference,
            voxel_size=candidate.setup.voxel_size,
            tolerance=self.tolerance,
        )

    def floor(self, candidate: Candidate) -> float:
        """The all-zero volume's score on the candidate's phantoms (mean over the seeds)."""
        for seed in self.seeds:
            self.trial(candidate, seed)  # simulated and reconstructed once, timed as such
        with candidate.timed("score_s"):
            return sum(self._score(candidate, seed, True) for seed in self.seeds) / len(self.seeds)

    def threshold(self, floor: float) -> float:
        """The value a score must beat: ``margin`` of the way from ``floor`` to a perfect score."""
        return floor + self.margin * (PERFECT_SCORES[self.metric] - floor)

    def __call__(self, candidate: Candidate) -> float:
        for seed in self.seeds:
            self.trial(candidate, seed)
        with candidate.timed("score_s"):
            score = sum(self._score(candidate, seed, False) for seed in self.seeds) / len(self.seeds)
        floor = self.floor(candidate)
        threshold = self.threshold(floor)
        beats = score > threshold if self.direction == "maximize" else score < threshold
        if not beats:
            unit = f" {self.unit}" if self.unit else ""
            warnings.warn(
                TaskFloorWarning(
                    f"{self.name} {score:.4g}{unit} does not beat the all-zero volume's {floor:.4g}{unit} by the "
                    f"margin ({'above' if self.direction == 'maximize' else 'below'} {threshold:.4g}{unit}, "
                    f"{self.margin:g} of the way to a perfect {PERFECT_SCORES[self.metric]:g}): the reconstruction "
                    "holds almost nothing of the phantom, and ranking on this score ranks noise. Fix: simulate "
                    "a sensor crop that holds the sub-images (lfm_studio.engine.optimize.crop.auto_crop), or "
                    "more photons / iterations.",
                    objective=self.name,
                    value=score,
                    floor=floor,
                    threshold=threshold,
                ),
                stacklevel=2,
            )
        return score


def _object_indices(truth: torch.Tensor) -> torch.Tensor:
    """Voxel indices ``(N, 3)`` of a bead phantom's beads (its non-zero voxels: one per bead)."""
    return (truth > 0).nonzero()


def task_score_from(options: dict[str, Any], metric: str) -> TaskScore:
    """A :class:`TaskScore` for ``metric`` with the run's task ``options`` (keys of :class:`TaskScore`;
    a None value takes the default)."""
    known = {"phantom", "method", "iterations", "photons", "seeds", "count", "tolerance", "margin"}
    return TaskScore(metric=metric, **{k: v for k, v in options.items() if k in known and v is not None})


def _task_factory(metric: str) -> ObjectiveFactory:
    def build(options: Mapping[str, Any]) -> Objective:
        return task_score_from(dict(options), metric)

    return build


for _metric, (_unit, _direction) in TASK_METRICS.items():
    register_objective(
        f"task_{_metric}",
        _task_factory(_metric),
        f"task score: {_metric} of reconstructed held-out phantoms ({_unit or 'unitless'}, {_direction})",
    )
