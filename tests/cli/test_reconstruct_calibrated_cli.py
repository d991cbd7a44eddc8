"""``lfm-studio calibrate`` -> ``simulate`` -> ``reconstruct --calibration`` on a misaligned raw frame.

Beads of a 3-depth ``lfm_10x_na03`` volume (8 x 8 lenslets, 19 px per lenslet on the model's
lattice) are seen through a raw camera with 19.37 x 19.31 px lenslets, a 1.5 deg rotation, an
offset, vignetting, noise, a dark offset of 100 ADU and hot pixels (as in
``tests/engine/calibration/test_end_to_end.py``, but through the command line and TIFF files).
References: the same beads imaged on the model's own lattice (aligned case), and the floors:
an all-zero volume and a plain crop of the raw frame reconstructed without calibration.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio import cli
from lfm_studio.engine.calibration import LensletLattice
from lfm_studio.engine.calibration.rectify import unrectify
from lfm_studio.engine.calibration.synthetic import expose, radial_vignetting
from lfm_studio.engine.design import load_preset, resolve_design, save_design
from lfm_studio.engine.io import read_volume
from lfm_studio.engine.phantoms import beads
from lfm_studio.engine.simulation import imaging_setup, simulate_psf

LENSLETS = 8
RAW_SHAPE = (188, 192)
BASELINE = 100.0


def _camera(image: torch.Tensor, *, seed: int, hot_fraction: float, vignetting: torch.Tensor | float = 1.0):
    frame, dark, _ = expose(
        image.double() * vignetting,
        baseline_adu=BASELINE,
        read_noise_e=1.5,
        gain_adu_per_e=1.0,
        hot_fraction=hot_fraction,
        hot_adu=3000.0,
        seed=seed,
    )
    return frame, dark


def _tiff(path, frame: torch.Tensor) -> str:
    tifffile.imwrite(path, frame.clamp(0, 65535).round().numpy().astype(np.uint16))
    return str(path)


def _pearson(a, b) -> float:
    return float(
        np.corrcoef(np.asarray(a, dtype=np.float64).ravel(), np.asarray(b, dtype=np.float64).ravel())[0, 1]
    )


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    folder = tmp_path_factory.mktemp("reconstruct_calibrated")
    base = load_preset("lfm_10x_na03")
    depths = {"depth_range_um": (-20.0, 20.0), "depth_step_um": 20.0}
    side = LENSLETS * 19 + 2
    design = base.updated(camera={**base.camera.model_dump(), "pixel_count": (side, side)}, depths=depths)
    setup = imaging_setup(simulate_psf(design))
    projector = setup.projector
    truth = beads(
        setup.volume_shape, count=6, voxel_size=setup.voxel_size, seed=3, intensity=1.0, margin=0.0
    ).data
    image = projector.forward(truth.float()).clamp_min(0.0).double()
    slab = torch.zeros(setup.volume_shape)
    slab[setup.volume_shape[0] // 2] = 1.0
    radiometry_model = projector.forward(slab).clamp_min(0.0).double()
    scale = 2e6 / float(image.sum())

    lattice = LensletLattice.from_geometry(
        (19.37, 19.31), math.radians(1.5), ((RAW_SHAPE[0] - 1) / 2 + 2.3, (RAW_SHAPE[1] - 1) / 2 - 3.1)
    )
    block = (-(LENSLETS // 2), LENSLETS, -(LENSLETS // 2), LENSLETS)
    vignetting = radial_vignetting(RAW_SHAPE, 0.2)
    raw, _ = _camera(
        unrectify(image, lattice, block, RAW_SHAPE) * scale, seed=2, hot_fraction=1e-3, vignetting=vignetting
    )
    radiometry_raw = unrectify(radiometry_model, lattice, block, RAW_SHAPE)
    radiometry, dark = _camera(
        radiometry_raw * (2000.0 / float(radiometry_raw.max())),
        seed=3,
        hot_fraction=1e-3,
        vignetting=vignetting,
    )
    aligned, _ = _camera(image * scale, seed=1, hot_fraction=0.0)
    top, left = ((r - s) // 2 for r, s in zip(RAW_SHAPE, image.shape, strict=True))
    nominal = folder / "nominal.json"  # the instrument's nominal optics on its raw camera
    save_design(design.updated(camera={**design.camera.model_dump(), "pixel_count": RAW_SHAPE}), nominal)
    yield {
        "folder": folder,
        "truth": truth.numpy(),
        "nominal": str(nominal),
        "raw": _tiff(folder / "raw.tif", raw),
        "raw_series": _tiff(folder / "raw_series.tif", torch.stack((raw, raw))),
        "crop": _tiff(folder / "crop.tif", raw[top : top + image.shape[0], left : left + image.shape[1]]),
        "aligned": _tiff(folder / "aligned.tif", aligned),
        "radiometry": _tiff(folder / "radiometry.tif", radiometry),
        "dark": _tiff(folder / "dark.tif", dark),
        "aligned_psf_shape": tuple(projector.image_shape),
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
    aligned = _reconstruct(files["aligned"], psf, tmp_path / "aligned.tif", "--baseline", str(BASELINE))
    crop = _reconstruct(files["crop"], psf, tmp_path / "crop.tif", "--baseline", str(BASELINE))
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
