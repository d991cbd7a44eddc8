"""The "Reconstruct video" dock widget: a recording file -> an OME-Zarr store opened as a lazy layer.

Video: the FLFM preset cropped to 128 x 128 px with 3 depths, 6 frames of camera counts (ADU,
Poisson, baseline 100, gain 2; fixed seeds) in a TIFF without camera metadata, so the baseline is
estimated and said in a warning. Reference: the engine's ``reconstruct_video`` called directly
with the same camera conversion (the widget must pass its fields through unchanged).
"""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio.engine.batch.extras import SCALE_MODULES

if any(importlib.util.find_spec(name) is None for name in SCALE_MODULES):
    pytest.skip("the optional scale extra (dask, zarr, ome-zarr) is not installed", allow_module_level=True)

import zarr

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.io import write_psf_stack
from lfm_studio.engine.simulation import imaging_setup, simulate_psf
from lfm_studio.engine.threads import torch_threads
from lfm_studio.napari_plugin import video_widget
from tests.napari.conftest import PLUGIN

FRAMES = 6  # two chunks of 4 and 2 frames (the engine's default chunk)


@pytest.fixture(autouse=True)
def one_thread():
    with torch_threads(1):  # the reference runs with 1 thread too: FFTs may differ in the last bit
        yield


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("napari_video")
    design = load_preset("flfm_guo2019")
    design = design.updated(depths=type(design.depths)(depth_range_um=(-20.0, 20.0), depth_step_um=20.0))
    with torch_threads(1):
        stack = simulate_psf(design, crop=128, dtype="float32")
        setup = imaging_setup(stack)
        volume = (torch.rand(setup.volume_shape, generator=torch.Generator().manual_seed(5)) > 0.9995).float()
        expected = setup.projector.forward(volume).numpy()
    expected = expected * (1500.0 / expected.max())
    frames = np.stack([100 + 2 * np.random.default_rng(s).poisson(expected) for s in range(FRAMES)])
    image = folder / "frames.tif"
    tifffile.imwrite(image, frames.astype(np.uint16), photometric="minisblack")
    return {"psf": write_psf_stack(folder / "psf.tif", stack), "frames": image}


@pytest.fixture
def widget(make_napari_viewer, files):
    viewer = make_napari_viewer()
    _, dock = viewer.window.add_plugin_dock_widget(PLUGIN, "Reconstruct video")
    dock.frames.setText(str(files["frames"]))
    dock.psf.setText(str(files["psf"]))
    dock.options.set_method("rl")
    dock.options.field("iterations").setValue(3)
    return viewer, dock


def _wait(qtbot, dock) -> None:
    qtbot.waitUntil(lambda: not dock.busy, timeout=120_000)


def _reference(files, out):
    from lfm_studio.engine.batch import open_frames, reconstruct_video
    from lfm_studio.engine.batch.camera import video_camera

    source = open_frames(files["frames"])
    camera, _ = video_camera(source)
    result = reconstruct_video(source, files["psf"], method="rl", iterations=3, output=out, camera=camera)
    return zarr.open_group(str(result.path), mode="r")["0"][:]


def test_a_recording_becomes_a_lazy_layer_equal_to_the_engine_run(widget, files, qtbot, notes, tmp_path):
    viewer, dock = widget
    dock.output.setText(str(tmp_path / "run"))  # .ome.zarr is added
    assert dock.start()
    _wait(qtbot, dock)
    assert notes.errors() == []
    assert any("estimated" in w for w in notes.warnings())  # no camera metadata: the baseline is estimated
    (layer,) = [layer for layer in viewer.layers if layer.metadata.get("kind") == "volume video"]
    level0 = np.asarray(layer.data[0])
    expected = _reference(files, tmp_path / "reference.ome.zarr")
    assert level0.shape == expected.shape and level0.shape[0] == FRAMES
    assert float(level0.std()) > 0.1 * float(level0.mean()) > 0  # not the all-zero or constant volume
    np.testing.assert_allclose(level0, expected, rtol=1e-5, atol=1e-5 * float(np.abs(expected).max()))
    assert any(f"{FRAMES} of {FRAMES} frames" in i for i in notes.infos())


def _cancel_after_the_first_chunk(monkeypatch):
    """Make the dock's next runs set their cancel token once a chunk is recorded (the engine then
    stops before the next chunk: no timing involved); returns the real ``run_video_job``."""
    original = video_widget.run_video_job

    def cancelling(job, progress, cancel):
        def report(done, total, message):
            progress(done, total, message)
            if "chunk" in message:
                cancel.set()

        return original(job, report, cancel)

    monkeypatch.setattr(video_widget, "run_video_job", cancelling)
    return original


def test_cancel_keeps_the_finished_chunk_and_resume_finishes_the_run(
    widget, qtbot, notes, tmp_path, monkeypatch
):
    viewer, dock = widget
    original = _cancel_after_the_first_chunk(monkeypatch)
    store = tmp_path / "run.ome.zarr"
    dock.output.setText(str(store))
    layers = len(viewer.layers)
    assert dock.start()
    _wait(qtbot, dock)
    assert len(viewer.layers) == layers and any("cancelled" in i for i in notes.infos())
    monkeypatch.setattr(video_widget, "run_video_job", original)

    assert dock.start(overwrite=False) is False  # exists, Resume not ticked, not agreed: kept
    assert store.exists() and dock.last_result is None
    dock.resume.setChecked(True)
    assert dock.start()
    _wait(qtbot, dock)
    assert dock.last_result.skipped == (0, 1, 2, 3) and dock.last_result.computed == (4, 5)
    assert len(viewer.layers) == layers + 1


def test_bad_fields_are_refused_naming_the_field(widget, qtbot, notes, tmp_path):
    _, dock = widget
    assert not dock.start()  # no output store
    assert "Output store: empty" in notes.errors()[-1]
    dock.output.setText(str(tmp_path / "run.ome.zarr"))
    dock.calibration.setText(str(tmp_path / "missing.json"))
    assert not dock.start()
    assert "Calibration: " in notes.errors()[-1] and "does not exist" in notes.errors()[-1]
    (tmp_path / "calib.json").write_text("{}")
    dock.calibration.setText(str(tmp_path / "calib.json"))
    dock.counts.setChecked(False)
    assert not dock.start()
    assert "raw frames are camera counts" in notes.errors()[-1]
    dock.resume.setChecked(True)
    dock.calibration.setText("")
    assert not dock.start()
    assert "nothing to resume" in notes.errors()[-1]
    assert not (tmp_path / "run.ome.zarr").exists() and not dock.busy


def test_without_the_scale_extra_the_widget_says_how_to_install_it(widget, notes, monkeypatch, tmp_path):
    from lfm_studio.engine.batch import extras

    _, dock = widget
    dock.output.setText(str(tmp_path / "run.ome.zarr"))
    monkeypatch.setattr(extras, "SCALE_MODULES", ("lfm_studio_no_such_module",))
    assert not dock.start() and not dock.busy
    assert 'pip install "lfm-studio[scale]"' in notes.errors()[-1]


def _write_frames(files, path, *, nan_frame: int | None = None):
    """The recording as float32 TIFF at ``path``; a NaN pixel in ``nan_frame`` makes that frame fail."""
    frames = tifffile.imread(files["frames"]).astype(np.float32)
    if nan_frame is not None:
        frames[nan_frame, 60, 60] = np.nan  # no camera writes NaN: the engine records the frame as failed
    tifffile.imwrite(path, frames, photometric="minisblack")
    return path


def _store_layers(viewer, store) -> list:
    return [layer for layer in viewer.layers if layer.metadata.get("source") == str(store)]


def _run_with_a_failed_frame(dock, files, qtbot, tmp_path):
    """A finished run whose frame 3 failed (a NaN pixel); returns the frames file and the store."""
    frames = _write_frames(files, tmp_path / "frames.tif", nan_frame=3)
    dock.frames.setText(str(frames))
    dock.counts.setChecked(False)  # photons: no baseline estimated (the NaN frame cannot change it)
    store = tmp_path / "run.ome.zarr"
    dock.output.setText(str(store))
    assert dock.start()
    _wait(qtbot, dock)
    return frames, store


def test_failed_frames_are_said_first_in_the_warning_and_in_the_status_line(
    widget, files, qtbot, notes, tmp_path
):
    _, dock = widget
    _, store = _run_with_a_failed_frame(dock, files, qtbot, tmp_path)
    warning = notes.warnings()[-1]  # a notification shows the start of its message
    assert warning.startswith(f"1 of {FRAMES} frames failed: frame 3: ValueError: ") and "NaN" in warning
    assert f"Store {store}: {FRAMES - 1} of {FRAMES} frames reconstructed (5 now, 0 before)." in warning
    status = dock.controls.status.text()
    assert status == f"done with problems: 1 of {FRAMES} frames failed (3). {video_widget.RESUME_FIX}"
    assert dock.controls.bar.value() == dock.controls.bar.maximum()  # the run did end


def test_no_to_replacing_the_store_clears_the_failed_frames_status(widget, files, qtbot, notes, tmp_path):
    _, dock = widget
    _run_with_a_failed_frame(dock, files, qtbot, tmp_path)
    assert dock.start(overwrite=False) is False  # exists, Resume not ticked, not agreed: nothing runs
    assert dock.controls.status.text() == "not run: run.ome.zarr kept"


def test_a_resume_replaces_the_stale_layer_of_its_store_and_keeps_other_layers(
    widget, files, qtbot, notes, tmp_path
):
    viewer, dock = widget
    mine = viewer.add_image(np.zeros((4, 4)), name="mine")
    frames, store = _run_with_a_failed_frame(dock, files, qtbot, tmp_path)
    (stale,) = _store_layers(viewer, store)
    assert "(1 failed)" in stale.name
    _write_frames(files, frames)  # repaired
    dock.resume.setChecked(True)
    assert dock.start()
    _wait(qtbot, dock)
    assert 3 in dock.last_result.computed and dock.last_result.failed == {}
    (layer,) = _store_layers(viewer, store)  # one layer for the store, in place of the stale one
    assert "failed" not in layer.name and stale not in viewer.layers
    assert list(viewer.layers) == [mine, layer]  # the user's own layer is kept, in its place
    assert np.asarray(layer.data[0][3]).max() > 0  # frame 3 now holds a reconstruction, not zeros
    assert f"{FRAMES} of {FRAMES} frames reconstructed" in notes.infos()[-1]
    assert dock.controls.status.text().startswith("done in")


def test_the_resume_label_and_docs_say_failed_frames_are_computed_again(widget):
    from pathlib import Path

    _, dock = widget
    assert "only missing or failed frames" in dock.resume.text()  # the studio's wording (video_dialog.py)
    docs = (Path(__file__).parents[2] / "docs" / "napari_plugin.md").read_text()
    resume = docs[docs.index("*Resume* (") :].split(")", 1)[0]
    assert "failed" in resume and "only the missing frames" not in docs


def test_frames_of_another_shape_are_told_the_docks_fields(files, tmp_path):
    small = tmp_path / "small.tif"
    tifffile.imwrite(small, np.zeros((2, 64, 64), np.uint16), photometric="minisblack")
    job = video_widget.VideoJob(small, files["psf"], tmp_path / "run.ome.zarr", "rl", {"iterations": 1})
    with pytest.raises(ValueError) as refused:
        video_widget.run_video_job(job, lambda *args: None, None)
    text = str(refused.value)
    assert "(64, 64) pixels" in text and "“Calibration (raw frames)” field" in text and "crop=" not in text
    assert not (tmp_path / "run.ome.zarr").exists()


def test_a_cancelled_replacement_keeps_the_previous_store_and_says_so(
    widget, qtbot, notes, tmp_path, monkeypatch
):
    _, dock = widget
    store = tmp_path / "run.ome.zarr"
    dock.output.setText(str(store))
    assert dock.start()
    _wait(qtbot, dock)
    before = np.asarray(zarr.open_group(str(store), mode="r")["0"][:])
    _cancel_after_the_first_chunk(monkeypatch)
    assert dock.start(overwrite=True)  # "Replace store?" answered Yes
    _wait(qtbot, dock)
    assert "the previous store run.ome.zarr is unchanged" in notes.infos()[-1]
    assert np.array_equal(np.asarray(zarr.open_group(str(store), mode="r")["0"][:]), before)
