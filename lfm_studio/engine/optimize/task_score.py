"""Task score (objective kind c): held-out phantoms imaged through a candidate and reconstructed.

For each held-out seed: a seeded phantom (beads or cell-like spheres) on the candidate's
volume grid, its light-field image at a photon budget with the design's camera (shot and
read noise; :func:`~lfm_studio.engine.simulation.light_field_image`), converted back to
photons, reconstructed with a named method (:func:`~lfm_studio.engine.reconstruct.reconstruct_frame`),
then scored with a metric a trivial volume cannot pass (:func:`score_volume`):

- ``ncc``: Pearson correlation with the truth (unitless, maximise; the all-zero volume scores 0);
- ``f1``: bead detection F1 against the phantom's own object positions (unitless, maximise;
  the all-zero volume scores 0);
- ``localisation``: mean distance from each true object to its matched peak, an unmatched
  object counting the match tolerance (um, minimise; the all-zero volume scores the tolerance,
  the worst value).

The score is the mean over the seeds. Seeds default to 1000 and up, apart from the seeds
small examples and tests use for anything they tune (0, 1, 2...).
"""

from __future__ import annotations

import math
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

HELD_OUT_SEEDS: tuple[int, ...] = (1000, 1001)


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
    if match.reference == 0:
        return 0.0
    total = float(match.errors.clamp_max(worst).sum()) + worst * (match.reference - match.matched)
    return total / match.reference


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
    """

    metric: str = "ncc"
    phantom: str = "beads"
    method: str = "rl"
    iterations: int = 20
    photons: float = 1e5
    seeds: tuple[int, ...] = HELD_OUT_SEEDS
    count: int | None = None
    tolerance: float = 2.0

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

    @property
    def name(self) -> str:
        return f"task_{self.metric}"

    @property
    def unit(self) -> str:
        return TASK_METRICS[self.metric][0]

    @property
    def direction(self) -> Direction:
        return TASK_METRICS[self.metric][1]

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

    def __call__(self, candidate: Candidate) -> float:
        scores = []
        for seed in self.seeds:
            truth, estimate, reference = self.trial(candidate, seed)
            with candidate.timed("score_s"):
                scores.append(
                    score_volume(
                        self.metric,
                        truth,
                        estimate,
                        reference=reference,
                        voxel_size=candidate.setup.voxel_size,
                        tolerance=self.tolerance,
                    )
                )
        return sum(scores) / len(scores)


def _object_indices(truth: torch.Tensor) -> torch.Tensor:
    """Voxel indices ``(N, 3)`` of a bead phantom's beads (its non-zero voxels: one per bead)."""
    return (truth > 0).nonzero()


def task_score_from(options: dict[str, Any], metric: str) -> TaskScore:
    """A :class:`TaskScore` for ``metric`` with the run's task ``options`` (keys of :class:`TaskScore`)."""
    known = {"phantom", "method", "iterations", "photons", "seeds", "count", "tolerance"}
    return TaskScore(metric=metric, **{k: v for k, v in options.items() if k in known})


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
