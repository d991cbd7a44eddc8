"""The default scores of a reconstruction, each beside the score of trivial volumes (floors).

:func:`scorecard` is what ``lfm-studio metrics`` prints and what the studio shows after
a reconstruction. Default scores, in the order they should be read:

1. **NCC**: Pearson correlation with the truth (:func:`~.correlation.ncc`); scale free.
2. **F1** (point and bead phantoms): local maxima matched to the truth's objects
   (:mod:`.peaks`, :mod:`.matching`), with precision, recall and the localisation error beside it.
3. **PSNR** (dB) and 4. **SSIM** on the stated normalisation (:data:`NORMALIZATION_TEXT`):
   the estimate is first put on the truth's scale (``normalize``), then both use the
   data range ``R`` (default the truth's ``max - min``).

Every score is also computed for the all-zero and the constant volume (:mod:`.floors`)
with the same settings; ``margin`` is the score minus the best floor, so a sparse
phantom's flattering PSNR/SSIM cannot hide that nothing was reconstructed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from lfm_studio.engine.image_quality.basic import Normalization, as_pair
from lfm_studio.engine.image_quality.correlation import ncc
from lfm_studio.engine.image_quality.curves import MetricReport, compare
from lfm_studio.engine.image_quality.floors import FLOORS, floor_volume
from lfm_studio.engine.image_quality.matching import DEFAULT_TOLERANCE, PeakMatch, peak_match
from lfm_studio.engine.image_quality.peaks import DEFAULT_THRESHOLD, find_peaks, looks_point_like

NORMALIZATION_TEXT = {
    "none": "in the truth's units (no scaling)",
    "scale": "after least-squares scale matching (a * estimate, a = <t, e> / <e, e>)",
    "affine": "after a least-squares fit a * estimate + c",
    "sum": "after scaling the estimate to the truth's total",
}
"""How PSNR and SSIM were normalised, in words (printed with them)."""
LABELS = {"ncc": "NCC", "f1": "F1", "psnr_db": "PSNR", "ssim": "SSIM"}


@dataclass(frozen=True)
class PeakOptions:
    """Peak detection and matching settings (see :mod:`lfm_studio.engine.image_quality.peaks`).

    threshold / truth_threshold: fraction of the estimate's / truth's maximum a peak must
    exceed; min_distance: suppression half-width (voxels); tolerance: match distance in
    voxels, or tolerance_um in micrometres (needs voxel sizes).
    """

    threshold: float = DEFAULT_THRESHOLD
    truth_threshold: float = DEFAULT_THRESHOLD
    min_distance: int = 1
    tolerance: float = DEFAULT_TOLERANCE
    tolerance_um: float | None = None


@dataclass(frozen=True)
class Score:
    """One score with the floors' scores of the same metric (higher is better for all)."""

    key: str
    value: float
    floors: dict[str, float] = field(default_factory=dict)

    @property
    def label(self) -> str:
        return LABELS[self.key]

    @property
    def unit(self) -> str:
        return "dB" if self.key == "psnr_db" else ""

    @property
    def margin(self) -> float:
        """The score minus the best floor (> 0: better than every trivial volume)."""
        return self.value - max(self.floors.values()) if self.floors else math.nan

    def to_dict(self) -> dict[str, Any]:
        return {
            "metric": self.key,
            "value": _number(self.value),
            **{f"{name}_floor": _number(v) for name, v in self.floors.items()},
            "margin": _number(self.margin),
        }


@dataclass(frozen=True)
class Scorecard:
    """The outcome of :func:`scorecard`.

    scores: NCC, F1 (when peaks were matched), PSNR, SSIM, in reading order.
    report: PSNR/SSIM details (data range, normalisation, scale, SSIM window, per-depth curves).
    peaks: the peak match, or None.
    """

    scores: tuple[Score, ...]
    report: MetricReport
    peaks: PeakMatch | None = None

    def score(self, key: str) -> Score | None:
        """The score ``key`` ("ncc", "f1", "psnr_db", "ssim"), None when not computed."""
        return next((s for s in self.scores if s.key == key), None)

    @property
    def normalization(self) -> str:
        """How PSNR and SSIM were computed, in words (normalisation and data range)."""
        return (
            f"PSNR/SSIM {NORMALIZATION_TEXT[self.report.normalize]}, "
            f"data range {self.report.data_range:.4g} (truth max - min unless given)"
        )

    def summary(self, *, noun: str = "objects", precise: bool = False) -> str:
        """One line, NCC and F1 first: ``NCC 0.82  F1 0.90 (9/10 beads)  PSNR 36.4 dB (zero floor 35.6)  ...``.

        ``precise`` prints PSNR with 3 and SSIM with 4 decimals (the CLI), else 2 and 3.
        """
        parts = []
        for s in self.scores:
            digits = {"ncc": 3, "f1": 2, "psnr_db": 3 if precise else 2, "ssim": 4 if precise else 3}[s.key]
            text = f"{s.label} {_fmt(s.value, digits)}{' ' + s.unit if s.unit else ''}"
            if s.key == "f1" and self.peaks is not None:
                text += f" ({self.peaks.describe(noun)})"
            if s.key in ("psnr_db", "ssim") and "zero" in s.floors:
                text += f" (zero floor {_fmt(s.floors['zero'], digits)})"
            parts.append(text)
        return "  ".join(parts)

    def table(self) -> list[str]:
        """Text rows: metric, value, one column per floor, margin over the best floor."""
        floors = list(self.scores[0].floors) if self.scores else []
        head = f"{'metric':<10}{'value':>11}" + "".join(f"{name + ' floor':>16}" for name in floors)
        rows = [head + f"{'margin':>11}"]
        for s in self.scores:
            digits = 3 if s.key == "psnr_db" else 4
            name = f"{s.label} ({s.unit})" if s.unit else s.label
            cells = "".join(f"{_fmt(s.floors[f], digits):>16}" for f in floors)
            margin = s.margin
            rows.append(
                f"{name:<10}{_fmt(s.value, digits):>11}{cells}"
                f"{('+' if margin >= 0 else '') + _fmt(margin, digits):>11}"
            )
        return rows

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the PSNR/SSIM report's keys, ``ncc``, ``peaks``, ``scores`` and ``floors``."""
        out = self.report.to_dict()
        ncc_score = self.score("ncc")  # always computed
        out["ncc"] = None if ncc_score is None else ncc_score.value
        out["normalization"] = self.normalization
        if self.peaks is not None:
            out["peaks"] = self.peaks.to_dict()
        out["scores"] = [s.to_dict() for s in self.scores]
        names = list(self.scores[0].floors) if self.scores else []
        out["floors"] = {name: {s.key: _number(s.floors[name]) for s in self.scores} for name in names}
        return out


def scorecard(
    truth,
    estimate,
    *,
    normalize: Normalization = "none",
    data_range: float | None = None,
    peaks: bool | None = None,
    peak_options: PeakOptions | None = None,
    voxel_size: Sequence[float] | None = None,
    reference=None,
    per_depth: bool = False,
    depths: Sequence[float] | None = None,
    floors: Sequence[str] = FLOORS,
) -> Scorecard:
    """NCC, F1, PSNR and SSIM of ``estimate`` against ``truth`` ``(Z, Y, X)``, each with its floors.

    Parameters
    ----------
    normalize, data_range : how PSNR/SSIM are computed (see :func:`~.curves.compare`).
    peaks : match local maxima (F1); ``None`` = when the truth looks like points or beads
        (:func:`~.peaks.looks_point_like`) or ``reference`` is given.
    peak_options : :class:`PeakOptions` (default thresholds 0.1, tolerance 2 voxels).
    voxel_size : ``(dz, dy, dx)`` metres; localisation errors are then in um.
    reference : ``(N, 3)`` object positions in voxel coordinates (instead of the truth's peaks).
    per_depth, depths : per-depth PSNR/SSIM curves of the estimate (see :func:`~.curves.compare`).
    floors : names of the floor volumes scored beside the estimate.
    """
    truth, estimate = as_pair(truth, estimate, name="scorecard")
    if truth.ndim != 3:
        raise ValueError(f"scorecard needs volumes (Z, Y, X); got shape {tuple(truth.shape)}.")
    options = peak_options or PeakOptions()
    if reference is None and peaks is not False:  # the truth's objects, found once for all volumes
        reference = find_peaks(truth, threshold=options.truth_threshold, min_distance=options.min_distance)
        use_peaks = looks_point_like(truth, peaks=reference) if peaks is None else True
    else:
        use_peaks = reference is not None if peaks is None else bool(peaks)
    measure = partial(compare, truth, normalize=normalize, data_range=data_range)  # PSNR/SSIM against truth

    def peak(volume) -> PeakMatch:
        return peak_match(
            truth, volume, threshold=options.threshold, truth_threshold=options.truth_threshold,
            min_distance=options.min_distance, tolerance=options.tolerance,
            tolerance_um=options.tolerance_um, voxel_size=voxel_size, reference=reference,
        )  # fmt: skip

    def values(volume, report: MetricReport, match: PeakMatch | None) -> dict[str, float]:
        out = {"ncc": float(ncc(truth, volume))}
        if match is not None:
            out["f1"] = match.f1
        return {**out, "psnr_db": report.psnr, "ssim": report.ssim}

    report = measure(estimate, per_depth=per_depth, depths=depths)
    match = peak(estimate) if use_peaks else None
    own = values(estimate, report, match)
    floor_values = {}
    for name in floors:
        volume = floor_volume(name, truth)
        floor_values[name] = values(volume, measure(volume), peak(volume) if use_peaks else None)
    scores = tuple(
        Score(key, v, {name: floor_values[name][key] for name in floors}) for key, v in own.items()
    )
    return Scorecard(scores, report, match)


def _fmt(value: float, digits: int) -> str:
    return f"{value:.{digits}f}" if math.isfinite(value) else ("inf" if value > 0 else "nan")


def _number(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None
