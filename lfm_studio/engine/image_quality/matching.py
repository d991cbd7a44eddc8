"""Peaks matched to reference objects: precision, recall, F1 and the localisation error.

Found peaks and reference objects (the truth's peaks, or a phantom's object positions)
are paired one to one, greedily by increasing distance, when closer than a tolerance
(Euclidean in voxel units, or in um with voxel sizes). Unpaired found peaks are false
positives, unpaired references misses; precision, recall and F1 follow, with the mean
and RMS distance of the pairs as the localisation error. Greedy pairing equals the
optimal assignment whenever each found peak has at most one reference within the
tolerance (separated beads).

Positions are ``(z, y, x)`` voxel coordinates; voxel sizes are in metres and reported
lengths in micrometres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from lfm_studio.engine.image_quality.basic import as_pair
from lfm_studio.engine.image_quality.peaks import DEFAULT_THRESHOLD, Peaks, find_peaks

DEFAULT_TOLERANCE = 2.0
"""Match distance in voxels (Euclidean in voxel units) when no tolerance in um is given."""
UM = 1e-6


@dataclass(frozen=True)
class PeakMatch:
    """Found peaks paired with reference objects (see :func:`match_peaks`).

    Attributes
    ----------
    found, reference : number of found peaks and of reference objects.
    pairs : ``(K, 2)`` int64, ``(found index, reference index)`` of each match.
    errors : ``(K,)`` float64 distance of each pair, in ``unit``.
    unit : "um" (voxel sizes known) or "voxels".
    tolerance : the largest distance of a pair, in ``tolerance_unit`` ("um" or "voxels").
    """

    found: int
    reference: int
    pairs: torch.Tensor
    errors: torch.Tensor
    unit: str
    tolerance: float
    tolerance_unit: str

    @property
    def matched(self) -> int:
        """True positives."""
        return int(self.pairs.shape[0])

    @property
    def precision(self) -> float:
        """Matched / found (1 when nothing was found and nothing was there, else 0 without peaks)."""
        if self.found == 0:
            return 1.0 if self.reference == 0 else 0.0
        return self.matched / self.found

    @property
    def recall(self) -> float:
        """Matched / reference (1 when there was nothing to find and nothing was found)."""
        if self.reference == 0:
            return 1.0 if self.found == 0 else 0.0
        return self.matched / self.reference

    @property
    def f1(self) -> float:
        """``2 TP / (2 TP + FP + FN)``: 0 for an empty estimate of a non-empty truth."""
        wrong = (self.found - self.matched) + (self.reference - self.matched)
        return 1.0 if self.matched + wrong == 0 else 2 * self.matched / (2 * self.matched + wrong)

    @property
    def mean_error(self) -> float:
        """Mean distance of the matched pairs in ``unit`` (NaN without a match)."""
        return float(self.errors.mean()) if self.matched else math.nan

    @property
    def rms_error(self) -> float:
        """Root-mean-square distance of the matched pairs in ``unit`` (NaN without a match)."""
        return float(self.errors.square().mean().sqrt()) if self.matched else math.nan

    def describe(self, noun: str = "objects", matched: str = "") -> str:
        """E.g. ``"9/10 beads, 1 false"``; ``matched`` follows the count (e.g. ``" matched within 2 voxels"``)."""
        false = self.found - self.matched
        return f"{self.matched}/{self.reference} {noun}{matched}" + (f", {false} false" if false else "")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready numbers (``null`` for an undefined localisation error)."""

        def number(v: float) -> float | None:
            return v if math.isfinite(v) else None

        return {
            "found": self.found,
            "reference": self.reference,
            "matched": self.matched,
            "precision": self.precision,
            "recall": self.recall,
            "f1": self.f1,
            f"mean_error_{self.unit}": number(self.mean_error),
            f"rms_error_{self.unit}": number(self.rms_error),
            f"tolerance_{self.tolerance_unit}": self.tolerance,
        }


def _positions(value, name: str) -> torch.Tensor:
    if isinstance(value, Peaks):
        value = value.positions
    p = torch.as_tensor(value, dtype=torch.float64).detach().cpu()
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{name} must be (N, 3) voxel coordinates (z, y, x); got shape {tuple(p.shape)}.")
    return p


def _voxel_scale(voxel_size: Sequence[float] | None) -> torch.Tensor | None:
    if voxel_size is None:
        return None
    scale = torch.as_tensor([float(v) for v in voxel_size], dtype=torch.float64)
    if scale.shape != (3,) or not bool(torch.isfinite(scale).all() and (scale > 0).all()):
        raise ValueError(f"voxel_size must be three lengths (dz, dy, dx) > 0 in metres; got {voxel_size!r}.")
    return scale / UM


def match_peaks(
    found,
    reference,
    *,
    tolerance: float = DEFAULT_TOLERANCE,
    tolerance_um: float | None = None,
    voxel_size: Sequence[float] | None = None,
) -> PeakMatch:
    """Pair ``found`` peaks with ``reference`` objects one to one, greedily by increasing distance.

    Parameters
    ----------
    found, reference : :class:`Peaks` or ``(N, 3)`` voxel coordinates ``(z, y, x)``.
    tolerance : largest pair distance in voxels (Euclidean in voxel units), used unless
        ``tolerance_um`` is given.
    tolerance_um : largest pair distance in micrometres (needs ``voxel_size``).
    voxel_size : ``(dz, dy, dx)`` in metres; when given, errors are reported in um.
    """
    f, ref = _positions(found, "found"), _positions(reference, "reference")
    scale = _voxel_scale(voxel_size)
    if tolerance_um is not None:
        if scale is None:
            raise ValueError(
                "tolerance_um needs voxel_size (metres). Fix: pass voxel_size or tolerance in voxels."
            )
        limit, limit_unit, metric = float(tolerance_um), "um", scale
    else:
        limit, limit_unit, metric = float(tolerance), "voxels", torch.ones(3, dtype=torch.float64)
    if not (math.isfinite(limit) and limit > 0):
        raise ValueError(f"the match tolerance must be a finite number > 0 {limit_unit}; got {limit!r}.")
    pairs = torch.zeros((0, 2), dtype=torch.int64)
    if len(f) and len(ref):
        delta = f[:, None, :] - ref[None, :, :]
        distance = (delta * metric).norm(dim=-1)
        candidates = (distance <= limit).nonzero()
        order = torch.argsort(distance[candidates[:, 0], candidates[:, 1]], stable=True)
        used_f, used_r, chosen = set(), set(), []
        for i, j in candidates[order].tolist():
            if i not in used_f and j not in used_r:
                used_f.add(i)
                used_r.add(j)
                chosen.append((i, j))
        if chosen:
            pairs = torch.tensor(chosen, dtype=torch.int64)
    unit = "um" if scale is not None else "voxels"
    offsets = (f[pairs[:, 0]] - ref[pairs[:, 1]]) * (scale if scale is not None else 1.0)
    return PeakMatch(len(f), len(ref), pairs, offsets.norm(dim=-1), unit, limit, limit_unit)


def peak_match(
    truth,
    estimate,
    *,
    threshold: float = DEFAULT_THRESHOLD,
    truth_threshold: float = DEFAULT_THRESHOLD,
    min_distance: int = 1,
    tolerance: float = DEFAULT_TOLERANCE,
    tolerance_um: float | None = None,
    voxel_size: Sequence[float] | None = None,
    reference=None,
) -> PeakMatch:
    """Peaks of ``estimate`` matched to the objects of ``truth`` (volumes ``(Z, Y, X)``).

    ``reference`` (``(N, 3)`` voxel coordinates, e.g. a phantom's ``indices``) replaces the
    truth's own peaks (found with ``truth_threshold``). See :func:`find_peaks` and
    :func:`match_peaks` for the other parameters.
    """
    truth, estimate = as_pair(truth, estimate, name="peak_match")
    found = find_peaks(estimate, threshold=threshold, min_distance=min_distance)
    if reference is None:
        reference = find_peaks(truth, threshold=truth_threshold, min_distance=min_distance)
    return match_peaks(
        found, reference, tolerance=tolerance, tolerance_um=tolerance_um, voxel_size=voxel_size
    )
