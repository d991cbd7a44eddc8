"""The sweep as Markdown tables (printed, written to docs), and reading them back.

One table per case, preceded by a ``### case`` heading and a line with the depths,
the reference's time and its convergence check. Columns: knob, value, time (s, the
fastest interleaved round), ratio to the standard preset measured in the same run,
worst-depth relative PSF error, reconstruction error, ``*`` on the Pareto front, notes,
then the reconstructed two-point resolution (lateral, axial, um) of the volume-grid rows
(blank on the others). A grid row's PSF and reconstruction errors read ``n/a (other grid)``.
Tables written before the resolution columns existed (8 columns) are read too.
"""

from __future__ import annotations

import math

from lfm_studio.bench.grid import GRID_KNOB_NAMES, NOT_COMPARABLE
from lfm_studio.bench.sweep import CaseResult, Row

LEGACY_COLUMNS = ("knob", "value", "time (s)", "time / standard", "PSF error", "recon error", "front", "note")
COLUMNS = (*LEGACY_COLUMNS, "lateral res. (um)", "axial res. (um)")


def _number(value: float, spec: str) -> str:
    """``value`` in ``spec``; no value (NaN: not measured) reads "n/a" (:func:`_float` reads it back)."""
    return "n/a" if math.isnan(value) else format(value, spec)


def _reference_check(change: float) -> str:
    """The summary line's convergence check; NaN: it was not run (``--quick``, ``--grid-only``)."""
    if math.isnan(change):
        return "refined reference not checked (--quick or --grid-only)"
    return f"refined reference differs by {format(change, '.2e')}"


def format_case(result: CaseResult) -> str:
    """The Markdown block of one case (heading, summary line, table)."""
    depths = ", ".join(f"{z:g}" for z in result.depths_um)
    lines = [
        f"### {result.case} ({result.kind})",
        "",
        f"Depths {depths} um; reference {result.reference_seconds:.1f} s; "
        + _reference_check(result.reference_change)
        + (f"; {result.note}" if result.note else "")
        + ".",
        "",
        "| " + " | ".join(COLUMNS) + " |",
        "|" + "|".join(["---"] * 2 + ["---:"] * 4 + [":---:", "---"] + ["---:"] * 2) + "|",
    ]
    for r in result.rows:
        grid = r.knob in GRID_KNOB_NAMES
        cells = (
            r.knob,
            r.value,
            _number(r.seconds, ".2f"),
            _number(r.ratio, ".2f"),
            NOT_COMPARABLE if grid else _number(r.psf_error, ".2e"),
            NOT_COMPARABLE if grid else _number(r.recon_error, ".2e"),
            "*" if r.front else "",
            r.note.replace("|", "/"),
            _number(r.lateral_um, ".3g") if grid else "",
            _number(r.axial_um, ".3g") if grid else "",
        )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def format_table(results: list[CaseResult]) -> str:
    """All cases, one Markdown block each."""
    return "\n".join(format_case(r) for r in results)


def _float(text: str) -> float:
    """The number in a cell; blank, ``nan`` and ``n/a ...`` give the one ``math.nan`` object,
    so rows read twice compare equal (dataclass equality compares fields by identity first)."""
    text = text.strip()
    if not text or text.startswith("n/a"):
        return math.nan
    value = float(text)
    return math.nan if math.isnan(value) else value


def parse_table(text: str) -> list[Row]:
    """The rows of every table in ``text`` (as written by :func:`format_table`), in order.

    The case of a row is the name in the nearest ``### name (kind)`` heading above it.
    """
    rows: list[Row] = []
    case = ""
    headers = {"| " + " | ".join(c) + " |": len(c) for c in (COLUMNS, LEGACY_COLUMNS)}
    width = len(COLUMNS)
    in_table = False
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("### "):
            case = stripped[4:].rsplit(" (", 1)[0].strip()
            in_table = False
        elif stripped in headers:
            in_table, width = True, headers[stripped]
        elif in_table and stripped.startswith("|") and not set(stripped) <= set("|-: "):
            cells = [c.strip() for c in stripped.strip("|").split("|")]
            if len(cells) != width:
                raise ValueError(f"table row has {len(cells)} cells, expected {width}: {line!r}")
            knob, value, seconds, ratio, psf, recon, front, note = cells[:8]
            lateral, axial = cells[8:] or ("", "")
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
                    _float(lateral),
                    _float(axial),
                )
            )
        elif not stripped.startswith("|"):
            in_table = False
    return rows
