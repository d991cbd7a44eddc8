"""``lfm-studio bench --quick`` on a tiny Fourier design: table, JSON, PNG, refusal to overwrite."""

from __future__ import annotations

import json
import os

import pytest

from lfm_studio.bench.pareto import pareto_front
from lfm_studio.bench.table import parse_table
from lfm_studio.cli import build_parser
from lfm_studio.engine.design import load_preset, save_design


def _no_constants(name: str) -> float:
    """``json.loads`` ``parse_constant``: NaN, Infinity and -Infinity are not JSON; fail on them."""
    raise AssertionError(f"{name} in a JSON document (not valid strict JSON)")


def _main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    return int(args.handler(args))


@pytest.fixture
def tiny_design(tmp_path):
    """Guo's FLFM on a 256 x 256 sensor of 9 um pixels, depths -10, 0, 10 um: seconds per sweep."""
    design = load_preset("flfm_guo2019")
    camera = type(design.camera)(
        **{**design.camera.model_dump(), "pixel_count": (256, 256), "pixel_pitch_um": 9.0}
    )
    depths = type(design.depths)(depth_range_um=(-10.0, 10.0), depth_step_um=10.0)
    path = tmp_path / "tiny.json"
    save_design(design.updated(camera=camera, depths=depths, name="tiny"), path)
    return path


@pytest.fixture
def plot_app(request):
    """The session's QApplication when there is a display (pytest-xvfb), so the plot reuses it:
    an offscreen one made by the plot would be inherited by the later Qt tests of this process
    (no OpenGL for napari). Without a display (``-p no:xvfb``) the plot makes its own."""
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return request.getfixturevalue("qapp")
    return None


def test_bench_quick_writes_a_parsable_table_json_and_png(plot_app, tiny_design, tmp_path, capsys):
    out = tmp_path / "bench"
    assert _main(["bench", "--design", str(tiny_design), "--quick", "--out", str(out), "--threads", "1"]) == 0
    printed = capsys.readouterr().out
    rows = parse_table(printed)
    labels = {f"{r.knob}={r.value}" for r in rows}
    assert {"preset=preview", "preset=standard", "preset=reference", "dtype=float64"} <= labels
    assert {r.case for r in rows} == {"tiny"}
    standard = next(r for r in rows if r.label == "preset=standard")
    assert standard.ratio == pytest.approx(1.0)
    assert all(r.seconds > 0 and r.psf_error >= 0 and r.recon_error >= 0 for r in rows)
    # The printed times are rounded to 0.01 s, so a front recomputed from the table can break ties
    # differently from the one the sweep computed from the measured times. Compare like with like:
    # the JSON keeps the unrounded times and errors the flags were computed from.
    # float64 differs from the float32 standard by rounding only; the paraxial model by much more.
    f64 = next(r for r in rows if r.label == "dtype=float64")
    paraxial = next(r for r in rows if r.label == "objective_model=paraxial")
    assert abs(f64.psf_error - standard.psf_error) < 1e-4 < paraxial.psf_error - standard.psf_error
    assert parse_table((out / "accuracy_table.md").read_text()) == rows
    document = json.loads((out / "accuracy.json").read_text(), parse_constant=_no_constants)
    assert document["cases"][0]["reference_change"] is None  # --quick: not checked
    assert "refined reference not checked (--quick or --grid-only)." in printed and "nan" not in printed
    assert [r["knob"] for r in document["cases"][0]["rows"]] == [r.knob for r in rows]
    measured = document["cases"][0]["rows"]
    assert [i for i, r in enumerate(measured) if r["front"]] == sorted(
        pareto_front([(r["seconds"], r["psf_error"]) for r in measured])
    )
    assert [r["front"] for r in measured] == [r.front for r in rows]  # the table prints the same flags
    assert (out / "accuracy_pareto.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(FileExistsError, match="--overwrite"):
        _main(["bench", "--design", str(tiny_design), "--quick", "--out", str(out)])


def test_bench_rejects_bad_repeats(tiny_design):
    with pytest.raises(ValueError, match="--repeats must be >= 1; got 0"):
        _main(["bench", "--design", str(tiny_design), "--repeats", "0"])
