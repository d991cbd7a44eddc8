"""The camera conversion of a video (shared by ``lfm-studio reconstruct --out x.ome.zarr`` and the studio):
the user's values win, then the TIFF's metadata, then a fallback camera, else an estimate with notes."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio.engine.batch import open_frames
from lfm_studio.engine.batch.camera import tiff_metadata, video_camera
from lfm_studio.engine.io import CameraCalibration, write_image

FRAMES = (100 + np.random.default_rng(1).poisson(5.0, size=(3, 16, 12))).astype(np.uint16)
RECORDED = {"baseline_adu": 90.0, "gain_adu_per_e": 2.0, "quantum_efficiency": 0.8, "read_noise_e": 1.2}
DESIGN_CAMERA = CameraCalibration(100.0, 0.5, 0.7, source="the design's camera", read_noise_e=1.0)


@pytest.fixture
def with_metadata(tmp_path):
    path = tmp_path / "recorded.tif"
    write_image(
        path, torch.from_numpy(FRAMES.astype(np.float32)), pixel_size=6.5e-6, metadata={"camera": RECORDED}
    )
    return open_frames(path)


@pytest.fixture
def bare(tmp_path):
    tifffile.imwrite(tmp_path / "bare.tif", FRAMES, photometric="minisblack")
    return open_frames(tmp_path / "bare.tif")


def test_the_tiff_metadata_wins_over_the_fallback(with_metadata):
    assert tiff_metadata(with_metadata.path)["camera"]["gain_adu_per_e"] == 2.0
    camera, notes = video_camera(with_metadata, fallback=DESIGN_CAMERA)
    assert notes == [] and camera.source == "image metadata"
    assert (camera.baseline_adu, camera.gain_adu_per_e, camera.quantum_efficiency) == (90.0, 2.0, 0.8)


def test_the_users_values_win_over_the_metadata(with_metadata):
    camera, notes = video_camera(
        with_metadata, baseline=95.0, gain=1.5, read_noise=0.5, fallback=DESIGN_CAMERA
    )
    assert notes == [] and (camera.baseline_adu, camera.gain_adu_per_e, camera.read_noise_e) == (
        95.0,
        1.5,
        0.5,
    )


def test_a_given_quantum_efficiency_wins_over_the_metadata_and_the_fallback(with_metadata, bare):
    camera, _ = video_camera(with_metadata, quantum_efficiency=0.5, fallback=DESIGN_CAMERA)
    assert (camera.baseline_adu, camera.quantum_efficiency) == (90.0, 0.5)  # the rest: the metadata's
    camera, notes = video_camera(
        bare, baseline=100.0, gain=2.0, quantum_efficiency=0.5, fallback=DESIGN_CAMERA
    )
    assert notes == [] and (camera.baseline_adu, camera.gain_adu_per_e, camera.quantum_efficiency) == (
        100.0,
        2.0,
        0.5,
    )


def test_without_metadata_the_fallback_is_used_and_named(bare):
    camera, notes = video_camera(bare, fallback=DESIGN_CAMERA)
    assert camera == DESIGN_CAMERA
    assert (
        len(notes) == 1
        and "bare.tif carries no camera metadata" in notes[0]
        and "the design's camera" in notes[0]
    )


def test_without_metadata_or_fallback_the_baseline_is_estimated_with_notes(bare, tmp_path):
    camera, notes = video_camera(bare)
    assert camera.source == "estimated" and not camera.gain_known
    assert 95.0 <= camera.baseline_adu <= 105.0  # the darkest pixels of the first frame (100 + Poisson(5))
    assert any("--baseline" in note for note in notes) and any("--gain" in note for note in notes)
    for t, frame in enumerate(FRAMES):  # a folder carries no header: the same estimate
        tifffile.imwrite(tmp_path / f"f_{t}.tif", frame)
    assert tiff_metadata(tmp_path) == {}
