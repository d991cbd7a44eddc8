"""``lfm-studio metrics``: NCC and F1 first, every score beside its all-zero and constant floors."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio import cli
from lfm_studio.cli.reconstruct import add_reconstruct_parsers
from lfm_studio.engine.image_quality import gaussian_filter
from lfm_studio.engine.io import write_volume

VOXEL = (4e-6, 0.5e-6, 0.5e-6)  # dz, dy, dx in metres
BEADS = [(1, 6, 6), (2, 20, 9), (3, 11, 25), (4, 26, 22), (2, 5, 28)]


def _truth() -> torch.Tensor:
    truth = torch.zeros(6, 32, 32, dtype=torch.float64)
    for z, y, x in BEADS:
        truth[z, y, x] = 100.0
    return truth


def _estimate(truth: torch.Tensor) -> torch.Tensor:
    """A blurred, slightly noisy copy shifted by one voxel in x (what a reconstruction looks like)."""
    noise = torch.rand(truth.shape, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    return gaussian_filter(torch.roll(truth, 1, dims=2), (0.5, 1.0, 1.0)) + 0.01 * noise


@pytest.fixture
def files(tmp_path):
    truth = _truth()
    paths = {name: tmp_path / f"{name}.tif" for name in ("truth", "estimate", "zero")}
    write_volume(paths["truth"], truth.float(), voxel_size=VOXEL, metadata={"phantom": "beads"})
    write_volume(paths["estimate"], _estimate(truth).float(), voxel_size=VOXEL)
    write_volume(paths["zero"], torch.zeros_like(truth).float(), voxel_size=VOXEL)
    return paths


def _run(capsys, files, *extra: str, estimate: str = "estimate") -> tuple[int, str, str]:
    capsys.readouterr()
    code = cli.main(["metrics", "--truth", str(files["truth"]), "--estimate", str(files[estimate]), *extra])
    out = capsys.readouterr()
    return code, out.out, out.err


def _json(capsys, files, *extra: str, estimate: str = "estimate") -> dict:
    code, out, err = _run(capsys, files, "--json", *extra, estimate=estimate)
    assert code == 0, err
    return json.loads(out)


def test_metrics_is_its_own_command():
    assert "metrics" in cli.build_parser()._subparsers._group_actions[0].choices
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    add_reconstruct_parsers(sub)
    assert set(sub.choices) == {"reconstruct"}


def test_json_scores_floors_and_peaks(capsys, files):
    report = _json(capsys, files, "--normalize", "scale")
    truth = _truth()
    r, mean_square = float(truth.max()), float(truth.square().mean())
    assert [s["metric"] for s in report["scores"]] == ["ncc", "f1", "psnr_db", "ssim"]
    zero = report["floors"]["zero"]
    assert zero["ncc"] == 0.0 and zero["f1"] == 0.0
    assert zero["psnr_db"] == pytest.approx(10 * math.log10(r**2 / mean_square), abs=1e-6)
    assert report["floors"]["constant"]["ncc"] == pytest.approx(0.0, abs=1e-12)
    for score in report["scores"]:
        best = max(score["zero_floor"], score["constant_floor"])
        assert score["margin"] == pytest.approx(score["value"] - best, abs=1e-12)
    # Measured: NCC +0.34, F1 +1, PSNR +0.5 dB over the floors, but SSIM 0.931 below the all-zero
    # volume's 0.937: blur plus a one-voxel shift is what SSIM of a sparse volume punishes most.
    margins = {s["metric"]: s["margin"] for s in report["scores"]}
    assert margins["ncc"] > 0.3 and margins["f1"] == 1.0 and margins["psnr_db"] > 0.3 and margins["ssim"] < 0
    ncc = float(np.corrcoef(truth.numpy().ravel(), _estimate(truth).float().double().numpy().ravel())[0, 1])
    assert report["ncc"] == pytest.approx(ncc, abs=1e-6)
    peaks = report["peaks"]
    assert (peaks["found"], peaks["reference"], peaks["matched"], peaks["f1"]) == (5, 5, 5, 1.0)
    assert peaks["mean_error_um"] == pytest.approx(0.5)  # one voxel of 0.5 um in x
    assert peaks["tolerance_voxels"] == 2.0 and "scale matching" in report["normalization"]
    assert report["psnr_db"] == report["scores"][2]["value"] and report["normalize"] == "scale"


def test_an_all_zero_estimate_scores_exactly_its_floor(capsys, files):
    report = _json(capsys, files, estimate="zero")
    values = {s["metric"]: s for s in report["scores"]}
    assert values["ncc"]["value"] == 0.0 and values["f1"]["value"] == 0.0
    assert report["peaks"]["found"] == 0 and report["peaks"]["mean_error_um"] is None
    assert values["psnr_db"]["value"] == values["psnr_db"]["zero_floor"]
    assert all(s["margin"] <= 0 for s in report["scores"])


def test_text_prints_ncc_and_f1_first_then_a_table_with_floors(capsys, files):
    report = _json(capsys, files, "--normalize", "scale")
    code, out, _ = _run(capsys, files, "--normalize", "scale")
    assert code == 0
    lines = out.splitlines()
    assert lines[0].startswith(
        f"NCC {report['ncc']:.3f}  F1 1.00 (5/5 objects)  PSNR {report['psnr_db']:.3f} dB"
    )
    assert f"SSIM {report['ssim']:.4f}" in lines[0]
    assert lines[1].split() == ["metric", "value", "zero", "floor", "constant", "floor", "margin"]
    psnr_row = lines[4].split()
    assert psnr_row[:2] == ["PSNR", "(dB)"]
    assert float(psnr_row[3]) == pytest.approx(report["floors"]["zero"]["psnr_db"], abs=1e-3)
    assert any(line.startswith("PSNR/SSIM after least-squares scale matching") for line in lines)
    assert any("localisation error mean 0.5 um" in line for line in lines)


def test_peaks_auto_on_off(capsys, files, tmp_path):
    assert "f1" not in [s["metric"] for s in _json(capsys, files, "--peaks", "off")["scores"]]
    # A smooth, extended truth (not a bead phantom, not point-like): no F1 unless asked for.
    smooth = gaussian_filter(torch.rand(6, 32, 32, generator=torch.Generator().manual_seed(2)), 3.0) + 1.0
    files = {**files, "truth": tmp_path / "smooth.tif"}
    write_volume(files["truth"], smooth.float(), voxel_size=VOXEL)
    assert "peaks" not in _json(capsys, files)
    assert "peaks" in _json(capsys, files, "--peaks", "on")


def test_tolerance_in_um(capsys, files):
    assert _json(capsys, files, "--tolerance-um", "0.4")["peaks"]["matched"] == 0  # the 0.5 um shift is out
    assert _json(capsys, files, "--tolerance-um", "0.6")["peaks"]["matched"] == 5


def test_bad_flags_are_named_errors(capsys, files, tmp_path):
    code, _, err = _run(capsys, files, "--peak-threshold", "1.5")
    assert code == 2 and "--peak-threshold" in err
    code, _, err = _run(capsys, files, "--tolerance-voxels", "0")
    assert code == 2 and "--tolerance-voxels" in err
    plain = tmp_path / "plain.tif"  # a TIFF without voxel sizes
    tifffile.imwrite(plain, _truth().float().numpy())
    code, _, err = _run(capsys, {**files, "truth": plain}, "--tolerance-um", "1")
    assert code == 2 and "--tolerance-um needs voxel sizes" in err
    # Without voxel sizes the errors are in voxels.
    report = _json(capsys, {**files, "truth": plain}, "--peaks", "on")
    assert report["peaks"]["mean_error_voxels"] == pytest.approx(1.0)


def test_frames_are_scored_one_by_one(capsys, files, tmp_path):
    truth = _truth()
    frames = torch.stack([_estimate(truth), torch.zeros_like(truth)]).float()
    files = {**files, "frames": tmp_path / "frames.tif"}
    write_volume(files["frames"], frames, voxel_size=VOXEL)
    report = _json(capsys, files, estimate="frames")
    first, second = report["frames"]
    assert first["peaks"]["f1"] == 1.0 and second["peaks"]["f1"] == 0.0
    code, out, _ = _run(capsys, files, estimate="frames")
    assert (
        code == 0 and out.startswith("frame 0: NCC") and "\nframe 1: NCC 0.000  F1 0.00 (0/5 objects)" in out
    )


def test_false_peaks_are_counted_after_the_matched_ones(capsys, files, tmp_path):
    """5 beads found where they are plus 2 far from any: '5/5 objects matched within 2 voxels, 2 false'."""
    estimate = _truth()
    estimate[0, 30, 2] = estimate[5, 2, 30] = 100.0
    files = {**files, "estimate": tmp_path / "false_peaks.tif"}
    write_volume(files["estimate"], estimate.float(), voxel_size=VOXEL)
    code, out, err = _run(capsys, files)
    assert code == 0, err
    line = next(line for line in out.splitlines() if line.startswith("peaks:"))
    assert line.startswith(
        "peaks: 5/5 objects matched within 2 voxels, 2 false; precision 0.714, recall 1.000"
    ), line
