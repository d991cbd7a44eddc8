"""Run time against error for every accuracy knob (``lfm-studio bench``, ``benchmarks/accuracy.py``).

Pieces: :mod:`cases` (designs, depths, crops), :mod:`knobs` (settings, reference,
presets as points), :mod:`grid` (volume-grid rows: time and two-point resolution),
:mod:`compute`, :mod:`metrics` (PSF and reconstruction error),
:mod:`timing` (interleaved rounds), :mod:`pareto`, :mod:`sweep`, :mod:`table`,
:mod:`plot` (PNG; imports pyqtgraph lazily). Headless: nothing here imports Qt at import time.
"""

from lfm_studio.bench.cases import BenchCase, bench_case, resolve_case, shipped_cases
from lfm_studio.bench.knobs import KnobSetting, preset_options, reference_plan, sweep_settings
from lfm_studio.bench.metrics import psf_error
from lfm_studio.bench.pareto import pareto_front
from lfm_studio.bench.plot import write_pareto_png
from lfm_studio.bench.sweep import CaseResult, Row, run_case
from lfm_studio.bench.table import format_table, parse_table

__all__ = [
    "BenchCase",
    "CaseResult",
    "KnobSetting",
    "Row",
    "bench_case",
    "format_table",
    "pareto_front",
    "parse_table",
    "preset_options",
    "psf_error",
    "reference_plan",
    "resolve_case",
    "run_case",
    "shipped_cases",
    "sweep_settings",
    "write_pareto_png",
]
