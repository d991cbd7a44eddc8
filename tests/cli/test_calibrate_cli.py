"""``lfm-studio calibrate``: a synthetic radiometry + dark pair in, a calibration file out; named errors."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio import cli
from lfm_studio.cli.errors import OUTPUT_REFUSED
from lfm_studio.engine.calibration import LensletLattice, load_calibration
from lfm_studio.engine.calibration.synthetic import conventional_design_for, fourier_frames, synthetic_frames
from lfm_studio.engine.design import load_preset, resolve_design, save_design

SHAPE = (256, 288)


def _tiff(path, frame: torch.Tensor) -> str:
    tifffile.imwrite(path, frame.clamp(0, 65535).round().numpy().astype(np.uint16))
    return str(path)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("calibrate_cli")
    truth = LensletLattice.from_geometry((15.38, 15.38), math.radians(1.4), (131.7, 140.2))
    frames = synthetic_frames(SHAPE, truth, disk_diameter=13.8, seed=3)
    design = folder / "design.json"
    save_design(conventional_design_for(15.38, SHAPE), design)
    far = folder / "far.json"
    save_design(conventional_design_for(15.38 * 1.4, SHAPE), far)
    noise = 100.0 + 20.0 * torch.rand(SHAPE, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    return {
        "folder": folder,
        "truth": truth,
        "design": str(design),
        "far": str(far),
        "radiometry": _tiff(folder / "radiometry.tif", frames.radiometry),
        "dark": _tiff(folder / "dark.tif", frames.dark),
        "noise": _tiff(folder / "noise.tif", noise),
        "saturated": _tiff(folder / "saturated.tif", (frames.radiometry * 40.0).clamp(max=30100.0)),
        "cropped_dark": _tiff(folder / "cropped_dark.tif", frames.dark[:, :280]),
    }


def _calibrate(files, out, *extra, radiometry="radiometry", dark="dark", design="design"):
    argv = ["calibrate", "--radiometry", files[radiometry], "--design", files[design], "--out", str(out)]
    if dark is not None:
        argv += ["--dark", files[dark]]
    return cli.main([*argv, *extra])


def test_calibrate_writes_a_calibration_close_to_the_truth(files, tmp_path, capsys):
    out = tmp_path / "calib.json"
    assert _calibrate(files, out) == 0
    printed = capsys.readouterr().out
    assert "lenslet pitch 15.3" in printed and f"wrote {out}" in printed
    calibration = load_calibration(out)
    assert len(list(tmp_path.glob("calib.dark.*.npz"))) == 1  # the dark frame, beside the calibration
    assert calibration.dark_frame.shape == SHAPE
    lattice = calibration.grid.lattice
    assert lattice.pitch == pytest.approx(files["truth"].pitch, abs=0.01)
    assert math.degrees(lattice.rotation) == pytest.approx(1.4, abs=0.02)
    # An existing file is kept unless --overwrite is given.
    before = out.read_bytes()
    assert _calibrate(files, out, dark=None) == OUTPUT_REFUSED
    assert "exists. Fix" in capsys.readouterr().err and out.read_bytes() == before
    assert _calibrate(files, out, "--overwrite", dark=None) == 0
    assert load_calibration(out).dark_level == 100.0  # no dark frame: the design camera's baseline


def test_calibrate_never_writes_over_its_input(files, capsys):
    radiometry = files["radiometry"]
    before = Path(radiometry).read_bytes()
    assert _calibrate(files, radiometry, "--overwrite", dark=None) == OUTPUT_REFUSED
    assert "also an input" in capsys.readouterr().err and Path(radiometry).read_bytes() == before


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ({"radiometry": "noise", "dark": None}, r"shows no lenslet grid.*Fix"),
        ({"design": "far"}, r"lenslet grid far from the design: measured pitch .* predicts 21.53 px.*Fix"),
        ({"radiometry": "saturated"}, r"radiometry frame is saturated.*30100 ADU.*Fix"),
        ({"radiometry": "dark", "dark": "radiometry"}, r"dark frame \(mean .*\) is not darker.*Fix"),
        ({"dark": "cropped_dark"}, r"dark frame shape \(256, 280\) differs.*\(256, 288\).*Fix"),
    ],
    ids=["no-grid", "far-pitch", "saturated", "dark-brighter", "shapes"],
)
def test_bad_input_is_named_with_a_fix(files, tmp_path, capsys, case, message):
    out = tmp_path / "calib.json"
    assert _calibrate(files, out, **case) == 2
    err = capsys.readouterr().err
    assert "lfm-studio calibrate: error:" in err
    assert re.search(message, err), err
    assert not out.exists()


def test_missing_file_is_named(files, tmp_path, capsys):
    missing = {**files, "radiometry": str(tmp_path / "nope.tif")}
    assert _calibrate(missing, tmp_path / "c.json") == 2
    assert "--radiometry" in capsys.readouterr().err


def test_calibrate_a_fourier_lfm(tmp_path, capsys):
    design = load_preset("flfm_guo2019")
    shape = (288, 288)
    design = design.updated(camera={**design.camera.model_dump(), "pixel_count": shape})
    radiometry, dark, truth = fourier_frames(design, shape, rotation_deg=0.8, shift=(1.5, -1.0), seed=6)
    save_design(design, tmp_path / "flfm.json")
    out = tmp_path / "calib.json"
    argv = [
        "calibrate",
        "--radiometry",
        _tiff(tmp_path / "r.tif", radiometry),
        "--dark",
        _tiff(tmp_path / "d.tif", dark),
    ]
    fitted = tmp_path / "fitted.json"
    argv += ["--design", str(tmp_path / "flfm.json"), "--design-out", str(fitted)]
    assert cli.main([*argv, "--out", str(out)]) == 0
    assert "9 sub-images (0 flagged)" in capsys.readouterr().out
    fit = load_calibration(out).sub_images
    assert float((fit.measured - truth).norm(dim=1).pow(2).mean().sqrt()) <= 0.1
    # --design-out: each lenslet at its measured sub-image centre, (x, y) um from the axis pixel (Y//2, X//2).
    pixel_um = design.camera.pixel_pitch_um
    centres = torch.tensor([lens.center_um for lens in resolve_design(str(fitted)).mla.lenslets])
    expected = torch.stack(((truth[:, 1] - shape[1] // 2), (truth[:, 0] - shape[0] // 2)), dim=1) * pixel_um
    assert float((centres.double() - expected).norm(dim=1).max()) <= 0.2 * pixel_um


def test_a_frame_that_does_not_fit_a_fourier_design_is_refused(files, tmp_path, capsys):
    """The conventional-LFM radiometry frame against the XLFM preset: a named refusal (exit 2), not a
    crash in the sub-image fit."""
    out = tmp_path / "calib.json"
    argv = ["calibrate", "--radiometry", files["radiometry"], "--design", "xlfm_cong2017", "--out", str(out)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "lfm-studio calibrate: error: the radiometry frame is 256 x 288 px, but" in err, err
    assert "27 sub-images" in err and "Fix: " in err and "Traceback" not in err
    assert not out.exists()


def test_ctrl_c_says_which_outputs_were_written(files, tmp_path, capsys, monkeypatch):
    from lfm_studio.cli import calibrate as calibrate_cli
    from lfm_studio.engine import calibration

    out, design_out = tmp_path / "calib.json", tmp_path / "rectified.json"

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:  # during the calibration: nothing written, and it says so
        patch.setattr(calibration, "calibrate", interrupt)
        assert _calibrate(files, out, "--design-out", str(design_out)) == 130
    assert "interrupted; no output was written." in capsys.readouterr().err and not out.exists()
    with monkeypatch.context() as patch:  # between the calibration and --design-out
        patch.setattr(calibrate_cli, "_save_psf_design", interrupt)
        assert _calibrate(files, out, "--design-out", str(design_out)) == 130
    err = capsys.readouterr().err
    assert f"interrupted; {out} had been written before it, not {design_out}." in err
    assert "Fix: run the same command again with --overwrite" in err and "no output was written" not in err
    assert load_calibration(out).grid is not None and not design_out.exists()
    with monkeypatch.context() as patch:  # after both were written (while the summary is printed)
        patch.setattr(calibrate_cli, "print", interrupt, raising=False)
        assert _calibrate(files, out, "--design-out", str(design_out), "--overwrite") == 130
    err = capsys.readouterr().err
    assert (
        f"{out}, {design_out} had been written completely before it; nothing else was to be written." in err
    )
