"""``lfm-studio reconstruct --calibration calib.json --out run.ome.zarr``: raw frames in a video run
give the volumes of the TIFF path with the same calibration (which rectifies a series frame by frame)."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import tifffile

if any(importlib.util.find_spec(name) is None for name in ("dask", "distributed", "zarr", "ome_zarr")):
    pytest.skip("the scale extra is not installed", allow_module_level=True)

import zarr

from lfm_studio import cli
from lfm_studio.engine.calibration import calibrate, save_calibration
from lfm_studio.engine.calibration.synthetic_scene import BASELINE_ADU, misaligned_bead_scene
from lfm_studio.engine.io import read_volume, write_psf_stack

ARGS = ["--method", "rl", "--iterations", "10"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """The misaligned bead scene: its calibration, the aligned PSF stack and 3 raw frames (ADU)."""
    folder = tmp_path_factory.mktemp("raw_video_cli")
    scene = misaligned_bead_scene(8)
    calib = save_calibration(
        calibrate(scene.radiometry, scene.nominal, dark=scene.dark), folder / "calib.json"
    )
    psf = write_psf_stack(folder / "psf.tif", scene.stack)
    lit = (scene.raw - BASELINE_ADU).clamp_min(0.0)
    raw = np.stack(
        [scene.raw.numpy(), (BASELINE_ADU + 0.5 * lit).numpy(), (BASELINE_ADU + 2.0 * lit).numpy()]
    )
    image = folder / "raw.tif"
    tifffile.imwrite(image, raw.astype(np.float32), photometric="minisblack")
    return {"psf": psf, "image": image, "calib": calib}


def _run(files, out, *extra: str) -> int:
    argv = ["reconstruct", "--psf", str(files["psf"]), "--image", str(files["image"]), "--out", str(out)]
    return cli.main([*argv, "--calibration", str(files["calib"]), *ARGS, *extra])


def test_raw_video_equals_the_tiff_path(files, tmp_path, capsys):
    tiff = tmp_path / "volume.tif"
    assert _run(files, tiff) == 0
    reference = read_volume(tiff).data.numpy()
    store = tmp_path / "run.ome.zarr"
    assert _run(files, store, "--chunk-frames", "2") == 0
    assert "3 computed now" in capsys.readouterr().out
    level0 = zarr.open_group(str(store), mode="r")["0"][:]
    assert level0.shape == reference.shape and float(np.abs(reference).max()) > 0
    np.testing.assert_allclose(level0, reference, rtol=1e-4, atol=1e-4 * float(np.abs(reference).max()))


def test_raw_video_refusals_name_the_option(files, tmp_path, capsys):
    store = tmp_path / "run.ome.zarr"
    assert _run(files, store, "--baseline", "100") == 2  # the calibration subtracts its dark frame
    assert "--baseline 100.0 with --calibration" in capsys.readouterr().err
    assert _run(files, store, "--lenslets", "6", "6") == 2  # a 6 x 6 block for the 8 x 8 lenslet PSF
    assert "--lenslets 8 8" in capsys.readouterr().err
    assert not store.exists()


def test_raw_frames_without_a_calibration_are_told_to_pass_it(files, tmp_path, capsys):
    store = tmp_path / "run.ome.zarr"
    argv = ["reconstruct", "--psf", str(files["psf"]), "--image", str(files["image"]), "--out", str(store)]
    assert cli.main([*argv, *ARGS, "--baseline", "100", "--gain", "1"]) == 2
    err = capsys.readouterr().err
    assert "(188, 192) pixels but the projector images" in err and "--calibration calib.json" in err
    assert "crop=" not in err  # the CLI has no such option
    assert not store.exists()


def test_a_one_frame_2d_raw_tiff_is_a_one_frame_video(files, tmp_path, capsys):
    single = tmp_path / "raw2d.tif"
    tifffile.imwrite(single, tifffile.imread(files["image"])[0], photometric="minisblack")  # (Y, X)
    store = tmp_path / "single.ome.zarr"
    argv = ["reconstruct", "--psf", str(files["psf"]), "--image", str(single), "--out", str(store)]
    assert cli.main([*argv, "--calibration", str(files["calib"]), *ARGS]) == 0
    assert "1 frames (1 computed now" in capsys.readouterr().out
    level0 = zarr.open_group(str(store), mode="r")["0"][:]
    assert level0.shape[0] == 1 and float(np.abs(level0).max()) > 0
