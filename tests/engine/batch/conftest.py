"""A tiny video shared by the batch tests: the FLFM preset with 3 depths, cropped to 128 x 128 px
(volume 3 x 93 x 93), 8 frames of Poisson-noisy random points (fixed seeds), and the serial per-frame
reference built independently of :mod:`lfm_studio.engine.batch` (its own PSF, its own loop)."""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio.engine.batch.extras import SCALE_MODULES

if any(importlib.util.find_spec(name) is None for name in SCALE_MODULES):
    collect_ignore_glob = ["test_*.py"]  # the optional scale extra is not installed

from lfm_studio.engine.design import Design, load_preset
from lfm_studio.engine.reconstruct.dispatch import reconstruct_frame
from lfm_studio.engine.simulation import imaging_setup, simulate_psf
from lfm_studio.engine.threads import torch_threads

CROP = 128
FRAMES = 8
ITERATIONS = 3
METHOD = "rl-accelerated"


@dataclass(frozen=True)
class Video:
    design: Design
    tiff: Path
    frames: np.ndarray  # (T, Y, X) float32 photons
    reference: np.ndarray  # (T, Z, Y, X) float32: the serial loop, 1 torch thread
    voxel_size: tuple[float, float, float]  # m


def serial_reference(design: Design, frames: np.ndarray, **options) -> np.ndarray:
    """The plain loop: one projector, reconstruct_frame per frame (call it with 1 torch thread)."""
    setup = imaging_setup(simulate_psf(design, crop=CROP, dtype="float32"))
    volumes = [
        reconstruct_frame(setup.projector, torch.from_numpy(frame), **options).numpy() for frame in frames
    ]
    return np.stack(volumes).astype(np.float32)


@pytest.fixture(autouse=True)
def one_thread():
    """Every in-process run uses 1 torch thread, as the reference and the Dask workers do: FFT results
    (the projector's OTFs included) may differ in the last bit between thread counts."""
    with torch_threads(1):
        yield


@pytest.fixture(scope="session")
def video(tmp_path_factory) -> Video:
    with torch_threads(1):
        return _make_video(tmp_path_factory)


def _make_video(tmp_path_factory) -> Video:
    design = load_preset("flfm_guo2019")
    design = design.updated(depths=type(design.depths)(depth_range_um=(-20.0, 20.0), depth_step_um=20.0))
    setup = imaging_setup(simulate_psf(design, crop=CROP, dtype="float32"))
    volume = (torch.rand(setup.volume_shape, generator=torch.Generator().manual_seed(3)) > 0.9995).float()
    expected = setup.projector.forward(volume.to(torch.float32)).numpy()
    expected = expected * (2000.0 / expected.max())
    frames = np.stack(
        [np.random.default_rng(seed).poisson(expected).astype(np.float32) for seed in range(FRAMES)]
    )
    tiff = tmp_path_factory.mktemp("video") / "frames.tif"
    tifffile.imwrite(tiff, frames)
    reference = serial_reference(design, frames, method=METHOD, iterations=ITERATIONS)
    return Video(design, tiff, frames, reference, setup.voxel_size)
