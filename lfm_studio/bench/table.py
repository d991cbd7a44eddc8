"""The sweep as Markdown tables (printed, written to docs), and reading them back.

One table per case, preceded by a ``### case`` heading and a line with the depths,
the reference's time and its convergence check. Columns: knob, value, time (s, the
fastest interleaved round), ratio to the standard preset measured in the same run,
worst-depth relative PSF error, reconstruction error, ``*`` on the Pareto front, notes.
"""

from __future__ import annotations

import math

from lfm_studio.bench.sweep import CaseResult, Row

COLUMNS = ("knob", "value", "time (s)", "time / standard", "PSF error", "recon error", "front", "note")


def _number(value: float, spec: str) -> str:
    return "nan" if math.isnan(value) else format(value, spec)


def format_case(result: CaseResult) -> str:
    """The Markdown block of one case (heading, summary line, table)."""
    depths = ", ".join(f"{z:g}" for z in result.depths_um)
    lines = [
        f"### {result.case} ({result.kind})",
        "",
        f"Depths {depths} um; reference {result.reference_seconds:.1f} s; "
        f"refined reference differs by {_number(result.reference_change, '.2e')}"
        + (f"; {result.note}" if result.note else "")
        + ".",
        "",
        "| " + " | ".join(COLUMNS) + " |",
        "|" + "|".join(["---"] * 2 + ["---:"] * 4 + [":---:", "---"]) + "|",
    ]
    for r in result.rows:
        cells = (
            r.knob,
            r.value,
            _number(r.seconds, ".2f"),
            _number(r.ratio, ".2f"),
            _number(r.psf_error, ".2e"),
            _number(r.recon_error, ".2e"),
            "*" if r.front else "",
            r.note.replace("|", "/"),
        )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def format_table(results: list[CaseResult]) -> str:
    """All cases, one Markdown block each."""
    return "\n".join(format_case(r) for r in results)


def _float(text: str) -> float:
    return float(text) if text.strip() else math.nan


def parse_table(text: str) -> list[Row]:
    """The rows of every table in ``text`` (as written by :func:`format_table`), in order.

    The case of a row is the name in the nearest ``### name (kind)`` heading above it.
    """
    rows: list[Row] = []
    case = ""
    header = "| " + " | ".join(COLUMNS) + " |"
    in_table = False
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("### "):
            case = stripped[4:].rsplit(" (", 1)[0].strip()
            in_table = False
        elif stripped == header:
            in_table = True
        elif in_table and stripped.startswith("|") and not set(stripped) <= set("|-: "):
            cells = [c.strip() for c in stripped.strip("|").split("|")]
            if len(cells) != len(COLUMNS):
                raise ValueError(f"table row has {len(cells)} cells, expected {len(COLUMNS)}: {line!r}")
            knob, value, seconds, ratio, psf, recon, front, note = cells
            rows.append(
                Row(
                    case,
                    knob,
                    value,
                    _float(seconds),
                    _float(ratio),
                    _float(psf),
                    _float(recon),
                    front == "*",
                    note,
                )
            )
        elif not stripped.startswith("|"):
            in_table = False
    return rows
