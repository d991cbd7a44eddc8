"""Raw camera frames in a video run: ``reconstruct_video(..., calibration=...)``.

The misaligned bead scene (:mod:`lfm_studio.engine.calibration.synthetic_scene`: a conventional
LFM seen through a raw camera with a rotated, off-pitch lenslet grid, vignetting, a dark offset
and hot pixels) is calibrated from its radiometry and dark frames. A three-frame raw video is then
reconstructed in the workers with the calibration and compared with the documented workaround,
the series rectified first (:func:`rectify_frame`) and reconstructed as dark-subtracted ADU: the
same volumes (to float rounding). The beads are found (NCC with the truth far above the all-zero
volume's 0), and every misuse is refused naming the parameter.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import tifffile
import torch
import zarr

from lfm_studio.engine.batch import reconstruct_video
from lfm_studio.engine.batch.raw_frames import _CACHE, cached_rectifier, raw_frame_spec
from lfm_studio.engine.calibration import calibrate, calibration_files, rectify_frame, save_calibration
from lfm_studio.engine.calibration.raw_camera import dark_subtracted_camera
from lfm_studio.engine.calibration.synthetic_scene import BASELINE_ADU, misaligned_bead_scene
from lfm_studio.engine.image_quality import ncc
from lfm_studio.engine.io import CameraCalibration

ITERATIONS = 20
METHOD = "rl"


@pytest.fixture(scope="module")
def raw_video(tmp_path_factory):
    """The scene, its calibration file, a 3-frame raw video (ADU) and the same series rectified."""
    folder = tmp_path_factory.mktemp("raw_video")
    scene = misaligned_bead_scene(8)
    calibration = calibrate(scene.radiometry, scene.nominal, dark=scene.dark)
    calib = save_calibration(calibration, folder / "calib.json")
    lit = (scene.raw - BASELINE_ADU).clamp_min(0.0)
    raw = np.stack(
        [scene.raw.numpy(), (BASELINE_ADU + 0.5 * lit).numpy(), (BASELINE_ADU + 2.0 * lit).numpy()]
    )
    frames = folder / "raw.tif"
    tifffile.imwrite(frames, raw.astype(np.float32), photometric="minisblack")
    rectified = folder / "rectified.tif"
    tifffile.imwrite(
        rectified,
        rectify_frame(raw.astype(np.float32), calibration).numpy().astype(np.float32),
        photometric="minisblack",
    )
    return {
        "scene": scene,
        "calibration": calibration,
        "calib": calib,
        "frames": frames,
        "rectified": rectified,
        "design": scene.stack.design,
    }


def _run(raw_video, out, **kwargs):
    return reconstruct_video(
        raw_video["frames"], raw_video["design"], method=METHOD, iterations=ITERATIONS, output=out,
        calibration=raw_video["calib"], **kwargs,
    )  # fmt: skip


def test_raw_frames_are_rectified_in_the_workers_as_the_series_rectified_first(raw_video, tmp_path):
    result = _run(raw_video, tmp_path / "raw.ome.zarr", chunk_frames=2)
    assert result.failed == {} and result.computed == (0, 1, 2)
    volumes = zarr.open_group(str(result.path), mode="r")["0"][:]

    camera = dark_subtracted_camera(raw_video["calibration"])  # baseline 0: the dark is subtracted
    reference = reconstruct_video(
        raw_video["rectified"], raw_video["design"], method=METHOD, iterations=ITERATIONS,
        output=tmp_path / "rectified.ome.zarr", camera=camera,
    )  # fmt: skip
    expected = zarr.open_group(str(reference.path), mode="r")["0"][:]
    np.testing.assert_allclose(volumes, expected, rtol=1e-4, atol=1e-4 * float(np.abs(expected).max()))

    truth = raw_video["scene"].truth
    scores = [float(ncc(truth, torch.from_numpy(v))) for v in volumes]
    assert min(scores) > 0.7  # measured 0.85; the all-zero and constant volumes score 0, the raw crop 0.00
    photons = volumes.reshape(3, -1).sum(axis=1)
    assert photons[1] / photons[0] == pytest.approx(0.5, rel=0.05)  # frame 1: half the light above dark
    assert photons[2] / photons[0] == pytest.approx(2.0, rel=0.05)


def test_the_run_records_the_calibration_and_a_resume_with_another_is_refused(raw_video, tmp_path):
    out = tmp_path / "raw.ome.zarr"
    _run(raw_video, out)
    record = zarr.open_group(str(out), mode="r").attrs["lfm_studio"]["run"]["calibration"]
    assert record["path"] == str(raw_video["calib"].resolve()) and len(record["sha256"]) == 64
    other = tmp_path / "copy" / "calib.json"
    other.parent.mkdir()
    for file in calibration_files(raw_video["calib"]):  # the JSON and its dark frame
        shutil.copy(file, other.parent)
    with pytest.raises(
        ValueError, match=r"the calibration \(calibration=.*--calibration.*\) differs \(path changed\)"
    ):
        reconstruct_video(
            raw_video["frames"], raw_video["design"], method=METHOD, iterations=ITERATIONS, output=out,
            calibration=other, resume=True,
        )  # fmt: skip


def test_a_worker_refuses_a_calibration_changed_since_the_run_started(raw_video, tmp_path):
    calib = tmp_path / "calib.json"
    for file in calibration_files(raw_video["calib"]):  # the JSON and its dark frame
        shutil.copy(file, tmp_path)
    spec, _ = raw_frame_spec(calib)
    _CACHE.clear()  # as in a fresh worker process
    calib.write_text(calib.read_text().replace("\n", " \n", 1))
    with pytest.raises(ValueError, match="changed or vanished"):
        cached_rectifier(spec)


def test_misuse_is_refused_naming_the_parameter(raw_video, tmp_path):
    out = tmp_path / "x.ome.zarr"
    with pytest.raises(ValueError, match=r"lenslets=\(4, 4\) needs calibration="):
        reconstruct_video(raw_video["frames"], raw_video["design"], output=out, lenslets=(4, 4))
    with pytest.raises(ValueError, match="baseline 100 ADU with calibration"):
        _run(raw_video, out, camera=CameraCalibration(baseline_adu=100.0, gain_adu_per_e=1.0))
    with pytest.raises(ValueError, match=r"lenslets=\(8, 8\)"):  # a 6 x 6 block for the 8 x 8 PSF
        _run(raw_video, out, lenslets=(6, 6))
    with pytest.raises(FileNotFoundError, match="calibration"):
        reconstruct_video(
            raw_video["frames"], raw_video["design"], output=out, calibration=tmp_path / "no.json"
        )
    cropped = tmp_path / "cropped.tif"
    tifffile.imwrite(cropped, tifffile.imread(raw_video["frames"])[:, :180, :180], photometric="minisblack")
    with pytest.raises(ValueError, match=r"\(180, 180\) pixels but calibration .* \(188, 192\)"):
        reconstruct_video(cropped, raw_video["design"], output=out, calibration=raw_video["calib"])
    assert not out.exists()  # every refusal comes before the store is created


def test_fourier_raw_frames_are_corrected_not_resampled(tmp_path):
    """Fourier LFM: the calibration corrects each raw frame (dark, defects, per-sub-image flat) and
    the fitted design's PSF images the raw frame's pixels; the video equals the series corrected first."""
    from lfm_studio.engine.calibration import fitted_design
    from lfm_studio.engine.calibration.synthetic_fourier_scene import misaligned_fourier_scene

    scene = misaligned_fourier_scene()
    calibration = calibrate(scene.radiometry, scene.nominal, dark=scene.dark)
    calib = save_calibration(calibration, tmp_path / "calib.json")
    design = fitted_design(None, calibration)
    raw = torch.stack([scene.raw, scene.raw]).numpy().astype(np.float32)
    frames = tmp_path / "raw.tif"
    tifffile.imwrite(frames, raw, photometric="minisblack")
    result = reconstruct_video(
        frames,
        design,
        method=METHOD,
        iterations=ITERATIONS,
        output=tmp_path / "raw.ome.zarr",
        calibration=calib,
    )
    corrected = tmp_path / "corrected.tif"
    tifffile.imwrite(corrected, rectify_frame(raw, calibration).numpy(), photometric="minisblack")
    reference = reconstruct_video(
        corrected, design, method=METHOD, iterations=ITERATIONS, output=tmp_path / "ref.ome.zarr",
        camera=dark_subtracted_camera(calibration),
    )  # fmt: skip
    volumes = zarr.open_group(str(result.path), mode="r")["0"][:]
    expected = zarr.open_group(str(reference.path), mode="r")["0"][:]
    assert result.failed == {} and float(np.abs(expected).max()) > 0
    np.testing.assert_allclose(volumes, expected, rtol=1e-4, atol=1e-4 * float(np.abs(expected).max()))


def test_a_resume_with_the_calibrations_own_block_given_explicitly_continues(raw_video, tmp_path):
    out = tmp_path / "raw.ome.zarr"
    _run(raw_video, out, chunk_frames=2)
    (out / "lfm_studio_status" / "chunk_000001.json").unlink()  # as if interrupted before frame 2
    block = raw_video["calibration"].block
    record = zarr.open_group(str(out), mode="r").attrs["lfm_studio"]["run"]["calibration"]
    assert record["lenslets"] == [block[1], block[3]] and record["block"] == list(
        block
    )  # effective, not None
    result = _run(raw_video, out, chunk_frames=2, lenslets=(block[1], block[3]))
    assert result.skipped == (0, 1) and result.computed == (2,)


def test_a_store_recorded_before_the_effective_block_was_kept_still_resumes(raw_video, tmp_path):
    out = tmp_path / "raw.ome.zarr"
    _run(raw_video, out, chunk_frames=2)
    (out / "lfm_studio_status" / "chunk_000001.json").unlink()
    document = json.loads((out / "zarr.json").read_text())
    record = document["attributes"]["lfm_studio"]["run"]["calibration"]
    del record["block"]
    record["lenslets"] = None  # as the earlier version recorded a run without lenslets=
    (out / "zarr.json").write_text(json.dumps(document))
    result = _run(raw_video, out, chunk_frames=2)
    assert result.skipped == (0, 1) and result.computed == (2,)
