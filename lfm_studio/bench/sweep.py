"""Run the accuracy sweep of one case: reference, its convergence check, every setting timed and scored.

The volume-grid rows (:mod:`lfm_studio.bench.grid`) are timed in the same interleaved rounds;
they carry a reconstructed two-point resolution instead of the PSF and reconstruction errors.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field

from lfm_studio.bench.cases import BenchCase
from lfm_studio.bench.compute import compute_stack, depth_first, reference_stack
from lfm_studio.bench.grid import GridSetting, grid_quality, grid_settings, grid_task
from lfm_studio.bench.knobs import KnobSetting, reference_plan, sweep_settings
from lfm_studio.bench.metrics import ITERATIONS, ReconstructionProbe, psf_error
from lfm_studio.bench.pareto import pareto_front
from lfm_studio.bench.timing import interleaved_times
from lfm_studio.engine.progress import ProgressCallback


@dataclass
class Row:
    """One setting's result: time (s, fastest interleaved round), ratio to the standard preset, errors.

    Volume-grid rows: ``psf_error`` and ``recon_error`` are NaN (not comparable: another grid),
    ``ratio`` is to the default grid's row, and ``lateral_um`` / ``axial_um`` hold the
    reconstructed two-point resolution (micrometres; inf: unresolved). NaN on the other rows.
    """

    case: str
    knob: str
    value: str
    seconds: float
    ratio: float
    psf_error: float
    recon_error: float
    front: bool = False
    note: str = ""
    lateral_um: float = math.nan
    axial_um: float = math.nan

    @property
    def label(self) -> str:
        """``knob=value``."""
        return f"{self.knob}={self.value}"


@dataclass
class CaseResult:
    """The sweep of one case."""

    case: str
    kind: str
    depths_um: tuple[float, ...]
    note: str
    reference_seconds: float
    reference_change: float  # PSF error of the refined reference against the reference (NaN: not checked)
    rows: list[Row] = field(default_factory=list)

    def as_dict(self) -> dict:
        """JSON-ready form (units in key names); a NaN or infinite number (not measured, not checked,
        not resolved) is ``None``, so the document is strict JSON (``null``, not ``NaN``)."""
        out = _finite_or_none(asdict(self))
        out["rows"] = [_finite_or_none(asdict(r)) for r in self.rows]
        return out


def _finite_or_none(record: dict) -> dict:
    """``record`` with its non-finite float values replaced by ``None``."""
    return {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in record.items()}


def run_case(
    case: BenchCase,
    *,
    quick: bool = False,
    repeats: int = 2,
    check_reference: bool = True,
    iterations: int = ITERATIONS,
    settings: list[KnobSetting] | None = None,
    grid: list[GridSetting] | None = None,
    grid_iterations: int | None = None,
    progress: ProgressCallback | None = None,
) -> CaseResult:
    """Time and score every setting of ``case`` against its converged reference.

    ``check_reference`` also computes the one-step-finer reference and reports how much it
    differs (the reference is converged when that is far below the tightest preset bound).
    ``grid``: the volume-grid settings (default :func:`~lfm_studio.bench.grid.grid_settings`:
    none when ``quick``); their resolution uses ``grid_iterations`` RL iterations (default
    :data:`~lfm_studio.bench.grid.RESOLUTION_ITERATIONS`).
    """
    from lfm_studio.bench.grid import RESOLUTION_ITERATIONS

    settings = settings if settings is not None else sweep_settings(case, quick=quick)
    grid = grid if grid is not None else grid_settings(case, quick=quick)
    total = (len(settings) + len(grid)) * repeats + len(grid) + 1 + int(check_reference)
    done = 0

    def report(message: str) -> None:
        nonlocal done
        if progress is not None:
            progress(min(done, total), total, f"{case.name}: {message}")
        done += 1

    report("reference")
    start = time.perf_counter()
    ref_stack = reference_stack(case, reference_plan(case))
    reference_seconds = time.perf_counter() - start
    reference = depth_first(ref_stack)
    probe = ReconstructionProbe.from_reference(ref_stack, iterations=iterations)
    change = math.nan
    if check_reference:
        report("refined reference (convergence check)")
        finer = reference_stack(case, reference_plan(case, refined=True))
        change = psf_error(depth_first(finer), reference)
        del finer

    errors: dict[int, tuple[float, float, str]] = {}

    def score(index: int, result) -> None:
        if index >= len(settings):  # a grid row: scored by its resolution below
            return
        stack, warned = result
        errors[index] = (psf_error(depth_first(stack), reference), probe.error(stack), "; ".join(warned))

    tasks = [lambda s=s: compute_stack(case, s.options) for s in settings]
    tasks += [grid_task(case, g) for g in grid]
    labels = [s.label for s in settings] + [g.label for g in grid]
    seconds = interleaved_times(
        tasks,
        repeats=repeats,
        first=score,
        before=lambda i, r: report(f"{labels[i]} (round {r + 1})"),
    )
    grid_seconds = seconds[len(settings) :]
    seconds = seconds[: len(settings)]
    base = next((t for s, t in zip(settings, seconds, strict=True) if s.label == "preset=standard"), math.nan)
    rows = [
        Row(case.name, s.knob, s.value, t, t / base, errors[i][0], errors[i][1], note=errors[i][2])
        for i, (s, t) in enumerate(zip(settings, seconds, strict=True))
    ]
    grid_base = next((t for g, t in zip(grid, grid_seconds, strict=True) if g.default), math.nan)
    for g, t in zip(grid, grid_seconds, strict=True):
        report(f"{g.label}: two-point resolution")
        try:
            quality = grid_quality(case, g, iterations=grid_iterations or RESOLUTION_ITERATIONS)
            note, lateral, axial = quality.note, quality.lateral_um, quality.axial_um
        except ValueError as error:  # e.g. no light reaches the crop: the row keeps its time, says why
            note, lateral, axial = (
                "resolution not measured: " + " ".join(str(error).split()),
                math.nan,
                math.nan,
            )
        rows.append(
            Row(case.name, g.knob, g.value, t, t / grid_base, math.nan, math.nan, note=note,
                lateral_um=lateral, axial_um=axial)
        )  # fmt: skip
    for i in pareto_front([(r.seconds, r.psf_error) for r in rows]):
        rows[i].front = True
    if progress is not None:
        progress(total, total, f"{case.name}: done")
    return CaseResult(
        case.name,
        case.kind,
        tuple(z * 1e6 for z in case.depths),
        case.note,
        reference_seconds,
        change,
        rows,
    )
