"""The Qt-free job of File > Reconstruct light-field video…: the studio's design and workflow settings
through :func:`lfm_studio.engine.batch.reconstruct_video`, with the job's progress and cancel.

Video: the small Fourier test design (256 x 256 px, 3 depths), 4 frames of camera counts (ADU,
shot and read noise, fixed seeds) of random points, in a multi-page TIFF without camera metadata
(so the design's camera converts them, as the studio does for its simulated images). Reference:
the plain serial loop written here (the engine's ``counts_to_photons`` and ``reconstruct_frame``
per frame, its own projector), compared to a tolerance: the paths differ (store, float32 frames).
"""

from __future__ import annotations

import importlib.util
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio.engine.batch.extras import SCALE_MODULES

if any(importlib.util.find_spec(name) is None for name in SCALE_MODULES):
    pytest.skip("the optional scale extra (dask, zarr, ome-zarr) is not installed", allow_module_level=True)

import zarr

from lfm_studio.engine.design import Design
from lfm_studio.engine.io import counts_to_photons
from lfm_studio.engine.io.camera_counts import design_camera
from lfm_studio.engine.progress import CancelledError
from lfm_studio.engine.reconstruct.dispatch import reconstruct_frame
from lfm_studio.engine.simulation import camera_of, imaging_setup, light_field_image, simulate_psf
from lfm_studio.engine.threads import torch_threads
from lfm_studio.ui.results import WorkflowSettings
from lfm_studio.ui.video_job import VideoRequest, reconstruct_video_job, scale_missing
from tests.ui.standins import small_fourier_design

FRAMES, ITERATIONS = 4, 3
SETTINGS = WorkflowSettings(method="rl-accelerated", iterations=ITERATIONS)


class Ctx:
    """A job context like :class:`lfm_studio.widgets.jobs.JobContext`; ``stop_after`` frames sets cancel."""

    def __init__(self, stop_after: int | None = None) -> None:
        self.cancel = threading.Event()
        self.reports: list[tuple[int, int, str]] = []
        self.stop_after = stop_after

    def progress(self, done: int, total: int, message: str = "") -> None:
        self.reports.append((done, total, message))
        if self.stop_after is not None and done >= self.stop_after and "chunk" in message:
            self.cancel.set()

    def partial(self, value) -> None:
        pass

    def check(self, message: str = "cancelled") -> None:
        if self.cancel.is_set():
            raise CancelledError(message)


@dataclass(frozen=True)
class Video:
    design: Design
    tiff: Path
    reference: np.ndarray  # (T, Z, Y, X) float32, the serial loop


@pytest.fixture(autouse=True)
def one_thread():
    with torch_threads(1):  # as the reference: FFT results may differ in the last bit between thread counts
        yield


@pytest.fixture(scope="module")
def video(tmp_path_factory) -> Video:
    with torch_threads(1):
        design = small_fourier_design()
        setup = imaging_setup(simulate_psf(design, dtype="float32"))
        points = torch.rand(setup.volume_shape, generator=torch.Generator().manual_seed(5)) > 0.998
        counts = [
            light_field_image(setup, points.float(), camera_of(design), photons=2e5, seed=t)[0]
            for t in range(FRAMES)
        ]
        frames = torch.stack(counts).numpy().astype(np.uint16)
        tiff = tmp_path_factory.mktemp("video_job") / "frames.tif"
        tifffile.imwrite(tiff, frames, photometric="minisblack")
        reference = []
        for frame in frames:
            photons, floor = counts_to_photons(
                torch.from_numpy(frame.astype(np.float32)), design_camera(design.camera), name="frame"
            )
            volume = reconstruct_frame(
                setup.projector, photons, method="rl-accelerated", iterations=ITERATIONS, background=floor
            )
            reference.append(volume.numpy())
    return Video(design, tiff, np.stack(reference).astype(np.float32))


def _request(video: Video, out: Path, **kwargs) -> VideoRequest:
    fields = {"frames": video.tiff, "chunk_frames": 1, **kwargs}
    return VideoRequest(output=out, design=video.design, settings=SETTINGS, **fields)


def _level0(path) -> np.ndarray:
    return np.asarray(zarr.open_group(str(path), mode="r")["0"][:])


def _close(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-4 * float(np.abs(b).max()))


def test_the_job_equals_the_serial_per_frame_loop(video, tmp_path):
    ctx = Ctx()
    run = reconstruct_video_job(ctx, _request(video, tmp_path / "run.ome.zarr", chunk_frames=3))
    result = run.result
    assert result.computed == tuple(range(FRAMES)) and result.skipped == () and result.failed == {}
    out = _level0(result.path)
    assert out.shape == video.reference.shape and out.std() > 0.1 * out.mean() > 0  # not trivial
    _close(out, video.reference)
    assert run.shown_frame == FRAMES - 1 and run.display is not None
    _close(run.volume.numpy(), video.reference[-1])
    assert ctx.reports[-1][:2] == (FRAMES, FRAMES)  # progress counted frames to the end
    assert any("3/4 frames" in message for _, _, message in ctx.reports)  # the engine's chunk progress
    assert any("carries no camera metadata" in note and "design's camera" in note for note in run.notes)
    summary = run.summary()
    assert str(result.path) in summary and f"{FRAMES} of {FRAMES} frames" in summary


def test_cancel_after_the_first_chunk_then_resume_computes_only_the_missing_frames(video, tmp_path):
    out = tmp_path / "run.ome.zarr"
    with pytest.raises(CancelledError):
        reconstruct_video_job(Ctx(stop_after=1), _request(video, out))
    records = sorted(p.name for p in (out / "lfm_studio_status").glob("chunk_*.json"))
    assert records == ["chunk_000000.json"]  # the first chunk (frame 0) only; the store is resumable
    first = _level0(out)[0].copy()

    run = reconstruct_video_job(Ctx(), _request(video, out, resume=True))
    assert run.result.skipped == (0,) and run.result.computed == (1, 2, 3)
    out_data = _level0(out)
    assert np.array_equal(out_data[0], first)  # not rewritten
    _close(out_data, video.reference)
    assert "3 computed now, 1 done before" in run.summary()


def test_failed_frames_are_listed_and_the_last_good_frame_is_shown(video, tmp_path):
    frames = tifffile.imread(video.tiff).astype(np.float32)
    frames[3, 100, 120] = np.nan  # no camera writes NaN: the engine records the frame as failed
    bad = tmp_path / "with_nan.tif"
    tifffile.imwrite(bad, frames, photometric="minisblack")
    run = reconstruct_video_job(Ctx(), _request(video, tmp_path / "run.ome.zarr", frames=bad, chunk_frames=2))
    assert list(run.result.failed) == [3] and "NaN" in run.result.failed[3]
    assert run.shown_frame == 2  # the last frame that was reconstructed
    _close(run.volume.numpy(), video.reference[2])
    summary = run.summary()
    assert "3 of 4 frames" in summary and "1 frame(s) failed" in summary and "frame 3: " in summary
    assert "run again with “Resume”" in summary

    tifffile.imwrite(
        bad, tifffile.imread(video.tiff).astype(np.float32), photometric="minisblack"
    )  # repaired
    resumed = reconstruct_video_job(
        Ctx(), _request(video, tmp_path / "run.ome.zarr", frames=bad, chunk_frames=2, resume=True)
    )
    assert resumed.result.computed == (3,) and resumed.result.failed == {}
    assert "4 of 4 frames" in resumed.summary() and "Frame(s) [3] had failed" in resumed.summary()
    _close(_level0(tmp_path / "run.ome.zarr"), video.reference)


def test_an_existing_store_is_not_replaced_without_being_asked(video, tmp_path):
    out = tmp_path / "run.ome.zarr"
    reconstruct_video_job(Ctx(), _request(video, out, chunk_frames=4))
    with pytest.raises(FileExistsError, match="resume"):
        reconstruct_video_job(Ctx(), _request(video, out, chunk_frames=4))
    with pytest.raises(ValueError, match="exclude each other"):
        _request(video, out, resume=True, overwrite=True)


def test_frames_of_another_shape_are_refused_naming_the_file_both_shapes_and_the_fix(video, tmp_path):
    small = tmp_path / "other_camera.tif"
    tifffile.imwrite(small, np.zeros((3, 200, 256), np.uint16), photometric="minisblack")
    with pytest.raises(ValueError) as refused:
        reconstruct_video_job(Ctx(), _request(video, tmp_path / "run.ome.zarr", frames=small))
    text = str(refused.value)
    assert str(small) in text and "(200, 256) pixels" in text and "images (256, 256) pixels" in text
    assert "Fix: open the design of the camera" in text
    assert not (tmp_path / "run.ome.zarr").exists()  # refused before anything was written


def test_a_missing_scale_extra_is_named_with_the_install_line(monkeypatch, video, tmp_path):
    from lfm_studio.engine.batch import extras

    assert scale_missing() is None
    monkeypatch.setattr(extras, "SCALE_MODULES", (*extras.SCALE_MODULES, "lfm_studio_no_such_module"))
    said = scale_missing()
    assert (
        said is not None and "lfm_studio_no_such_module" in said and 'pip install "lfm-studio[scale]"' in said
    )
    with pytest.raises(extras.MissingExtraError, match="pip install"):
        reconstruct_video_job(Ctx(), _request(video, tmp_path / "run.ome.zarr"))


def test_raw_frames_with_a_calibration_equal_the_series_rectified_first(tmp_path):
    """Raw frames of a misaligned conventional LFM (the calibration tests' scene) with the calibration
    in the request: the job's volumes equal the engine run on the series rectified first."""
    from lfm_studio.engine.batch import reconstruct_video
    from lfm_studio.engine.calibration import calibrate, rectify_frame, save_calibration
    from lfm_studio.engine.calibration.raw_camera import dark_subtracted_camera
    from lfm_studio.engine.calibration.synthetic_scene import misaligned_bead_scene
    from lfm_studio.ui.video_job import video_options

    scene = misaligned_bead_scene(8)
    calibration = calibrate(scene.radiometry, scene.nominal, dark=scene.dark)
    calib = save_calibration(calibration, tmp_path / "calib.json")
    raw = torch.stack([scene.raw, scene.raw]).numpy().astype(np.float32)
    frames = tmp_path / "raw.tif"
    tifffile.imwrite(frames, raw, photometric="minisblack")
    design = scene.stack.design  # the rectified design: its projector images the rectified frames
    request = VideoRequest(frames, tmp_path / "raw.ome.zarr", design, SETTINGS, calibration=calib)
    run = reconstruct_video_job(Ctx(), request)
    assert run.result.failed == {} and any("rectified with calib.json" in note for note in run.notes)

    rectified = tmp_path / "rectified.tif"
    tifffile.imwrite(rectified, rectify_frame(raw, calibration).numpy(), photometric="minisblack")
    method, options = video_options(SETTINGS)
    reference = reconstruct_video(
        rectified, design, method=method, options=options, output=tmp_path / "ref.ome.zarr",
        camera=dark_subtracted_camera(calibration),
    )  # fmt: skip
    expected = _level0(reference.path)
    assert float(np.abs(expected).max()) > 0
    _close(_level0(run.result.path), expected)


def test_a_calibration_with_frames_in_photons_is_refused(video, tmp_path):
    with pytest.raises(ValueError, match="raw frames are camera counts"):
        _request(video, tmp_path / "run.ome.zarr", counts=False, calibration=tmp_path / "calib.json")


def test_raw_frames_with_the_nominal_design_open_are_told_to_open_the_rectified_design(tmp_path, monkeypatch):
    """The nominal (raw-camera) design open plus a calibration: the rectified frames are not its
    sensor; the fix names the studio's way (open rectified.json), not a command-line flag."""
    from lfm_studio.engine.batch import projectors
    from lfm_studio.engine.calibration import calibrate, save_calibration
    from lfm_studio.engine.calibration.synthetic_scene import misaligned_bead_scene

    scene = misaligned_bead_scene(8)
    calib = save_calibration(
        calibrate(scene.radiometry, scene.nominal, dark=scene.dark), tmp_path / "calib.json"
    )
    frames = tmp_path / "raw.tif"
    tifffile.imwrite(frames, scene.raw[None].numpy().astype(np.float32), photometric="minisblack")
    monkeypatch.setattr(projectors, "cached_projector", lambda spec: None)  # the refusal comes first
    request = VideoRequest(frames, tmp_path / "raw.ome.zarr", scene.nominal, SETTINGS, calibration=calib)
    with pytest.raises(ValueError) as refused:
        reconstruct_video_job(Ctx(), request)
    text = str(refused.value)
    assert "rectified with" in text and "Fix: open the rectified design (File > Open… rectified.json" in text
    assert "--lenslets" not in text and "lenslets=(" not in text
    assert not (tmp_path / "raw.ome.zarr").exists()
