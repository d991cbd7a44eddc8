"""Pareto front on hand-made points; the Markdown table round trip; the raster fallback PNG."""

from __future__ import annotations

import math
import zlib

from lfm_studio.bench.pareto import pareto_front
from lfm_studio.bench.plot import _render_raster
from lfm_studio.bench.sweep import CaseResult, Row
from lfm_studio.bench.table import format_table, parse_table
from lfm_studio.bench.timing import interleaved_times


def test_pareto_front_of_a_hand_made_point_set():
    points = [
        (1.0, 0.10),  # 0: fastest -> front
        (2.0, 0.05),  # 1: front
        (2.0, 0.08),  # 2: dominated by 1 (same time, larger error)
        (3.0, 0.05),  # 3: dominated by 1 (slower, same error)
        (4.0, 0.01),  # 4: front
        (5.0, 0.02),  # 5: dominated by 4
        (0.5, 0.50),  # 6: front (fastest of all)
        (4.0, 0.01),  # 7: equal to 4 -> kept too
        (1.5, math.nan),  # 8: no error measured -> never on the front
    ]
    assert pareto_front(points) == [6, 0, 1, 4, 7]


def test_pareto_front_edge_cases():
    assert pareto_front([]) == []
    assert pareto_front([(1.0, 1.0)]) == [0]
    assert pareto_front([(1.0, 0.0), (2.0, 0.0)]) == [0]  # exact (zero-error) settings: the fastest wins


def _result() -> CaseResult:
    rows = [
        Row("tiny", "preset", "standard", 1.25, 1.0, 1.5e-3, 2.0e-4, True, ""),
        Row(
            "tiny",
            "propagator",
            "asm (full field, s=1)",
            3.5,
            2.8,
            7.25e-2,
            math.nan,
            False,
            "SamplingWarning: x",
        ),
        Row("tiny", "dtype", "float64", 2.0, 1.6, 0.0, 0.0, True, ""),
    ]
    return CaseResult("tiny", "fourier", (-10.0, 0.0, 10.0), "a note", 4.5, 3.2e-5, rows)


def test_table_round_trip():
    text = format_table([_result(), _result()])
    rows = parse_table(text)
    assert len(rows) == 6
    first = rows[1]
    assert (first.case, first.knob, first.value) == ("tiny", "propagator", "asm (full field, s=1)")
    assert (first.seconds, first.ratio, first.psf_error) == (3.5, 2.8, 7.25e-2)
    assert math.isnan(first.recon_error) and not first.front and first.note == "SamplingWarning: x"
    assert [r.front for r in rows[:3]] == [True, False, True]
    assert "refined reference differs by 3.20e-05" in text


def test_raster_fallback_is_a_valid_png():
    data = _render_raster([_result()])
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    start = data.index(b"IDAT") + 4
    length = int.from_bytes(data[start - 8 : start - 4], "big")
    raw = zlib.decompress(data[start : start + length])
    assert len(raw) == height * (1 + 3 * width)
    assert raw.count(bytes((30, 90, 220))) > 0  # the preset point is drawn in blue


def test_interleaved_times_runs_rounds_in_order_and_keeps_the_fastest():
    calls: list[int] = []
    firsts: list[tuple[int, int]] = []
    tasks = [lambda i=i: calls.append(i) or i for i in range(3)]
    times = interleaved_times(tasks, repeats=2, first=lambda i, r: firsts.append((i, r)))
    assert calls == [0, 1, 2, 0, 1, 2]  # interleaved: every task once per round
    assert firsts == [(0, 0), (1, 1), (2, 2)]
    assert len(times) == 3 and all(t >= 0 for t in times)


def test_log_ticks_label_one_two_five_or_decades():
    from lfm_studio.bench.plot import log_ticks

    major, minor = log_ticks(0.03, 4.0)
    assert [label for _, label in major] == ["0.02", "0.05", "0.1", "0.2", "0.5", "1", "2", "5"]
    assert minor == [] and all(math.isclose(p, math.log10(float(t))) for p, t in major)
    major, minor = log_ticks(1e-3, 1e3)  # six decades: decades labelled, 2 and 5 unlabelled
    assert [label for _, label in major] == ["0.001", "0.01", "0.1", "1", "10", "100", "1000"]
    assert len(minor) == 12 and {label for _, label in minor} == {""}
    assert log_ticks(0.0, 1.0) == [[], []]


def test_grid_rows_and_legacy_tables_round_trip():
    result = _result()
    result.rows.append(
        Row("tiny", "voxels_per_lenslet", "7", 2.5, 1.4, math.nan, math.nan, False, "voxel 1", 2.25, math.inf)
    )
    result.rows.append(
        Row("tiny", "dtype", "float64", 2.5, 1.4, 1e-3, math.nan, False, "", math.nan, math.nan)
    )
    text = format_table([result])
    assert "| n/a (other grid) | n/a (other grid) |" in text and "| 2.25 | inf |" in text
    assert "nan" not in text and "| 1.00e-03 | n/a |" in text  # a value not measured reads n/a
    rows = parse_table(text)
    assert rows[3] == result.rows[3]  # NaN cells read back as the one math.nan object
    assert math.isnan(rows[4].recon_error) and abs(rows[4].psf_error - 1e-3) < 1e-12
    assert all(math.isnan(r.lateral_um) and math.isnan(r.axial_um) for r in rows[:3])
    # A table written before the resolution columns existed (8 columns) still reads.
    legacy = "\n".join(
        line.rsplit(" | ", 2)[0] + " |" if line.startswith("|") else line
        for line in format_table([_result()]).splitlines()
    )
    old = parse_table(legacy)
    assert [(r.knob, r.psf_error) for r in old] == [(r.knob, r.psf_error) for r in _result().rows]
