"""``lfm-studio calibrate`` -> ``simulate`` -> ``reconstruct --calibration`` on a misaligned raw frame.

Beads of a 3-depth ``lfm_10x_na03`` volume (8 x 8 lenslets, 19 px per lenslet on the model's
lattice) are seen through a raw camera with 19.37 x 19.31 px lenslets, a 1.5 deg rotation, an
offset, vignetting, noise, a dark offset of 100 ADU and hot pixels
(:func:`lfm_studio.engine.calibration.synthetic_scene.misaligned_bead_scene`, the scene of
``tests/engine/calibration/test_end_to_end.py``), through the command line and TIFF files.
References: the same beads imaged on the model's own lattice (aligned case), and the floors:
an all-zero volume and a plain crop of the raw frame reconstructed without calibration.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio import cli
from lfm_studio.engine.calibration.synthetic_scene import BASELINE_ADU, misaligned_bead_scene
from lfm_studio.engine.design import resolve_design, save_design
from lfm_studio.engine.io import read_volume


def _tiff(path, frame: torch.Tensor) -> str:
    tifffile.imwrite(path, frame.clamp(0, 65535).round().numpy().astype(np.uint16))
    return str(path)


def _pearson(a, b) -> float:
    a, b = np.asarray(a, dtype=np.float64).ravel(), np.asarray(b, dtype=np.float64).ravel()
    return float(np.corrcoef(a, b)[0, 1])


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("reconstruct_calibrated")
    scene = misaligned_bead_scene()
    nominal = folder / "nominal.json"  # the instrument's nominal optics on its raw camera
    save_design(scene.nominal, nominal)
    yield {
        "folder": folder,
        "truth": scene.truth.numpy(),
        "nominal": str(nominal),
        "raw": _tiff(folder / "raw.tif", scene.raw),
        "raw_series": _tiff(folder / "raw_series.tif", torch.stack((scene.raw, scene.raw))),
        "crop": _tiff(folder / "crop.tif", scene.crop),
        "aligned": _tiff(folder / "aligned.tif", scene.aligned),
        "radiometry": _tiff(folder / "radiometry.tif", scene.radiometry),
        "dark": _tiff(folder / "dark.tif", scene.dark),
    }
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def calibrated(files):
    """calibrate (with --design-out) and simulate the PSF from the written design, through the CLI."""
    folder = files["folder"]
    calib, rectified, psf = folder / "calib.json", folder / "rectified.json", folder / "psf.tif"
    argv = ["calibrate", "--radiometry", files["radiometry"], "--dark", files["dark"], "--design"]
    assert cli.main([*argv, files["nominal"], "--out", str(calib), "--design-out", str(rectified)]) == 0
    assert resolve_design(str(rectified)).camera.pixel_count == (164, 164)  # ceil(8.5 x 19.23 px)
    assert cli.main(["simulate", str(rectified), "--out", str(psf)]) == 0
    return {"calibration": str(calib), "psf": str(psf)}


def _reconstruct(image: str, psf: str, out, *extra: str) -> np.ndarray:
    argv = [
        "reconstruct",
        "--image",
        image,
        "--psf",
        psf,
        "--out",
        str(out),
        "--gain",
        "1",
        "--read-noise",
        "1.5",
    ]
    assert cli.main([*argv, *extra]) == 0
    return read_volume(out).data.numpy()


def test_calibrated_raw_frame_reconstructs_like_the_aligned_one(files, calibrated, tmp_path):
    truth, psf = files["truth"], calibrated["psf"]
    calibration = ("--calibration", calibrated["calibration"])
    volume = _reconstruct(files["raw"], psf, tmp_path / "calibrated.tif", *calibration)
    assert volume.shape == truth.shape
    aligned = _reconstruct(files["aligned"], psf, tmp_path / "aligned.tif", "--baseline", str(BASELINE_ADU))
    crop = _reconstruct(files["crop"], psf, tmp_path / "crop.tif", "--baseline", str(BASELINE_ADU))
    scores = {
        name: _pearson(v, truth) for name, v in (("calibrated", volume), ("aligned", aligned), ("crop", crop))
    }
    assert scores["aligned"] > 0.8, scores  # measured 0.976; calibrated 0.950, crop -0.002
    assert scores["calibrated"] >= scores["aligned"] - 0.05, scores
    assert scores["crop"] < 0.3, scores  # without calibration the beads are lost
    # The all-zero floor: zero volume scores 0 Pearson (undefined) and a relative L2 error of 1.
    relative = np.linalg.norm(volume / volume.sum() * truth.sum() - truth) / np.linalg.norm(truth)
    assert relative < 1.0, relative
    # A (T, Y, X) series is rectified frame by frame: each frame gives the single frame's volume.
    series = _reconstruct(files["raw_series"], psf, tmp_path / "series.tif", *calibration)
    assert series.shape == (2, *truth.shape)
    assert np.allclose(series[1], volume, rtol=1e-4, atol=1e-6 * float(np.abs(volume).max()))


def test_the_dark_level_is_subtracted_once(files, calibrated, tmp_path, capsys):
    args = ["--image", files["raw"], "--psf", calibrated["psf"], "--calibration", calibrated["calibration"]]
    out = tmp_path / "v.tif"
    assert cli.main(["reconstruct", *args, "--out", str(out), "--baseline", "100"]) == 2
    assert re.search(
        r"--baseline 100.0 with --calibration .*twice.*Fix: drop --baseline", capsys.readouterr().err
    )
    assert not out.exists()


def test_a_psf_of_another_lattice_is_named_with_both_shapes_and_the_fix(files, calibrated, tmp_path, capsys):
    small = tmp_path / "small.json"
    base = resolve_design(files["nominal"])
    save_design(base.updated(camera={**base.camera.model_dump(), "pixel_count": (120, 120)}), small)
    psf = tmp_path / "small_psf.tif"
    assert cli.main(["simulate", str(small), "--out", str(psf)]) == 0
    capsys.readouterr()
    out = tmp_path / "v.tif"
    argv = ["reconstruct", "--image", files["raw"], "--psf", str(psf), "--out", str(out)]
    assert cli.main([*argv, "--calibration", calibrated["calibration"]]) == 2
    err = capsys.readouterr().err
    assert re.search(r"rectified to \(152, 152\) pixels \(8 x 8 lenslets of 19 px\)", err), err
    assert re.search(r"images \(114, 114\) pixels\. Fix: .*--design-out.*--lenslets 6 6", err), err
    assert not out.exists()
    # The suggested --lenslets fixes it.
    assert cli.main([*argv, "--calibration", calibrated["calibration"], "--lenslets", "6", "6"]) == 0
    assert read_volume(out).data.shape[0] == 3


def test_lenslets_without_calibration_is_refused(files, calibrated, tmp_path, capsys):
    argv = [
        "reconstruct",
        "--image",
        files["aligned"],
        "--psf",
        calibrated["psf"],
        "--out",
        str(tmp_path / "v.tif"),
    ]
    assert cli.main([*argv, "--lenslets", "4", "4"]) == 2
    assert "--lenslets 4 4 needs --calibration" in capsys.readouterr().err


def test_a_bead_psf_with_a_conventional_calibration_is_refused_with_the_fix(
    files, calibrated, tmp_path, capsys
):
    out = tmp_path / "v.tif"
    argv = ["reconstruct", "--image", files["raw"], "--psf", calibrated["psf"], "--out", str(out)]
    assert cli.main([*argv, "--calibration", calibrated["calibration"], "--measured"]) == 2
    err = capsys.readouterr().err
    assert re.search(
        r"--measured with --calibration .*conventional-LFM calibration.*one PSF per depth", err
    ), err
    assert re.search(r"Fix: drop --measured .*--design-out rectified\.json", err), err
    assert not out.exists()
