"""Plain-text table of a :class:`~lfm_studio.engine.performance.report.DesignMetrics` report.

Row names are the JSON key names (``lateral_resolution_um``), so what a user reads in
the terminal is what a script finds in ``--json`` output.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from lfm_studio.engine import units
from lfm_studio.engine.performance.report import UNIT_SCALE, DesignMetrics, record_to_dict

_OUTCOME = {True: "PASS", False: "FAIL", None: "unknown"}


def format_value(value: Any) -> str:
    """A table cell: 4 significant digits, ``a .. b`` for ranges, ``n/a`` for None."""
    if value is None:
        return "n/a"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple)):
        if value and all(isinstance(v, str) for v in value):
            return f"{len(value)} note(s)"
        return " .. ".join(format_value(v) for v in value)
    return str(value)


def align(rows: Sequence[Sequence[str]], *, indent: str = "  ") -> list[str]:
    """Rows of cells as lines with left-aligned columns."""
    widths = [max(len(row[i]) for row in rows if i < len(row)) for i in range(max(map(len, rows)))]
    return [indent + "  ".join(cell.ljust(widths[i]) for i, cell in enumerate(row)).rstrip() for row in rows]


def _section(title: str, record: dict[str, Any]) -> list[str]:
    rows = [[key, format_value(value)] for key, value in record.items() if key != "notes"]
    return [title, *align(rows)]


def format_metrics_table(metrics: DesignMetrics) -> str:
    """The whole report as aligned text: closed forms, measurements, requirements, notes."""
    lines = [
        f"{metrics.design_name}  (kind {metrics.kind}, wavelength_nm {metrics.wavelength / units.nm:.4g})",
        "",
    ]
    lines += _section("closed form", record_to_dict(metrics.closed_form))
    if metrics.measured is not None:
        lines += ["", *_section("measured on a simulated PSF stack", record_to_dict(metrics.measured))]
    if metrics.requirements:
        rows = [["requirement", "basis", "value", "margin", "result"]]
        for c in metrics.requirements:
            unit = f" {c.unit}" if c.unit else ""
            scale = UNIT_SCALE[c.unit]
            value = "n/a" if c.value is None else f"{c.value / scale:.4g}{unit}"
            margin = "" if c.margin is None else f"{c.margin / scale:+.4g}{unit} ({c.relative_margin:+.0%})"
            rows.append([f"{c.label} {c.comparison} {c.limit / scale:.4g}{unit}", c.basis, value, margin,
                         _OUTCOME[c.passed]])  # fmt: skip
        lines += ["", f"requirements: {metrics.requirement_set}", *align(rows)]
        lines.append(f"  requirements_met: {_OUTCOME[metrics.requirements_met]}")
    notes = metrics.closed_form.notes
    if notes:
        lines += ["", "notes", *(f"  - {note}" for note in notes)]
    return "\n".join(lines)
