"""``lfm-studio info``: registered through ``add_info_parser`` on a stand-alone parser."""

from __future__ import annotations

import argparse
import json

import pytest

from lfm_studio.cli import info as info_cli
from lfm_studio.cli import main
from lfm_studio.engine.design import load_preset, save_design
from lfm_studio.engine.performance import DesignMetrics, format_metrics_table


def run(argv, capsys):
    parser = argparse.ArgumentParser(prog="lfm-studio")
    info_cli.add_info_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["info", *argv])
    code = args.handler(args)
    out, err = capsys.readouterr()
    return code, out, err


def test_table_lists_the_metrics_by_key_name_and_the_requirements(capsys):
    code, out, err = run(["xlfm_cong2017"], capsys)
    assert code == 0 and err == ""
    for key in ("magnification", "number_of_views", "lateral_resolution_um", "axial_resolution_um",
                "depth_of_field_um", "field_of_view_um", "field_of_view_limit"):  # fmt: skip
        assert key in out
    assert "XLFM after Cong et al. 2017" in out
    assert "depth_of_field >= 200 um" in out and "PASS" in out and "FAIL" in out
    # Rayleigh by default: 0.61 lambda / NA_eff = 0.61 x 0.525 um x 16 = 5.124 um
    lines = [line for line in out.splitlines() if line.startswith("  lateral_resolution_um")]
    assert lines and float(lines[0].split()[-1]) == pytest.approx(0.61 * 0.525 * 16, rel=1e-3)
    assert "lateral_resolution (Rayleigh 0.61 lambda/NA) <= 3 um" in out
    code, out, _ = run(["xlfm_cong2017", "--criterion", "abbe"], capsys)
    lines = [line for line in out.splitlines() if line.startswith("  lateral_resolution_um")]
    assert code == 0 and float(lines[0].split()[-1]) == pytest.approx(0.525 * 16 / 2, rel=1e-3)
    assert "lateral_resolution (Abbe lambda/(2 NA)) <= 3 um" in out


def test_a_conventional_lateral_row_names_the_lenslet_sampling_not_the_criterion(capsys):
    # Prevedel: the 7.5 um is pitch / M = 150 um / 20, not Rayleigh 0.61 x 0.525 um / 0.5 = 0.64 um;
    # --criterion abbe changes the diffraction term only, so the row stays the sampling limit.
    for argv in (["lfm_prevedel2014"], ["lfm_prevedel2014", "--criterion", "abbe"]):
        code, out, _ = run(argv, capsys)
        row = next(line for line in out.splitlines() if line.startswith("  lateral_resolution ("))
        assert code == 0 and row.startswith(
            "  lateral_resolution (lenslet sampling pitch/M, same for every criterion) <= 3 um"
        )
        assert float(row.split("closed_form")[1].split()[0]) == pytest.approx(150 / 20)
        assert "Rayleigh" not in row and "Abbe" not in row


def test_json_output_parses_and_has_units_in_keys(capsys):
    code, out, _ = run(["lfm_10x_na03", "--json"], capsys)
    assert code == 0
    data = json.loads(out)
    assert data["kind"] == "conventional"
    assert data["closed_form"]["lateral_resolution_um"] == pytest.approx(12.5)
    assert data["measured"] is None


def test_a_design_file_path_works(tmp_path, capsys):
    path = tmp_path / "mine.json"
    save_design(load_preset("flfm_guo2019"), path)
    code, out, _ = run([str(path), "--json"], capsys)
    assert code == 0 and json.loads(out)["closed_form"]["field_of_view_um"] == pytest.approx(66.5)


def test_unknown_design_exits_2_with_a_message(capsys):
    code = main(["info", "no_such_preset"])  # the refusal is printed by cli.main, like every command's
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert err.startswith("lfm-studio info: error: ") and "no_such_preset" in err and "Fix:" in err


def test_measure_on_a_conventional_design_says_why_it_cannot(capsys):
    code, out, err = run(["lfm_prevedel2014", "--measure", "--json"], capsys)
    assert code == 0
    assert "shift-invariant PSF per depth" in err and "lfm-studio resolution" in err
    assert "not implemented" not in err and "no PSF model" not in err  # the PSF model exists
    assert json.loads(out)["measured"] is None


def test_measure_adds_measured_values(monkeypatch, capsys, guo_psf):
    # The shared stack is exactly what --measure computes for this preset; reuse it (one simulation per run).
    monkeypatch.setattr(info_cli, "measurement_psf", lambda design: guo_psf)
    code, out, err = run(["flfm_guo2019", "--measure", "--json"], capsys)
    assert code == 0 and "15 depths on 296 x 296 pixels" in err
    measured = json.loads(out)["measured"]
    assert measured["focus_depth_um"] == 0.0  # the lenslets' focus, not merely the sharpest slice
    assert measured["lateral_two_point_um"] == pytest.approx(2.3, rel=0.05)
    table = format_metrics_table(DesignMetrics.from_json(out))  # what the table mode prints
    assert "measured on a simulated PSF stack" in table and "axial_two_point_um" in table
