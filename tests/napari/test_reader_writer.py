"""Reader and writer: our TIFFs open with physical scale and metadata and save back unchanged;
foreign files are left to other readers; design files open as a PSF layer computed in the background."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio.engine.design import save_design
from lfm_studio.engine.io import (
    LightFieldImage,
    Volume,
    read_image,
    read_psf_stack,
    read_volume,
    write_image,
    write_psf_stack,
    write_volume,
)
from lfm_studio.engine.psf_stack import ConventionalPatterns, PSFStack
from lfm_studio.engine.simulation import simulate_psf
from lfm_studio.engine.units import nm, um
from lfm_studio.napari_plugin import design_reader
from lfm_studio.napari_plugin.reader import get_reader
from lfm_studio.napari_plugin.sample_data import sample_design
from tests.napari.conftest import PLUGIN

DEPTHS = (-3 * um, 0.0, 5 * um)  # non-uniform on purpose: mean step 4 um


def _rand(*shape: int, seed: int = 0) -> torch.Tensor:
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed))


def _open_one(viewer, path):
    layers = viewer.open(path, plugin=PLUGIN)
    assert len(layers) == 1
    return layers[0]


def _save(viewer, layer, path) -> None:
    viewer.layers.selection = {layer}
    assert viewer.layers.save(str(path), selected=True, plugin=PLUGIN) == [str(path)]


def test_psf_stack_round_trip_keeps_scale_depths_and_design(make_napari_viewer, tmp_path):
    design = sample_design()
    stack = PSFStack(_rand(3, 16, 12), DEPTHS, 6.5 * um, 8.96, 680 * nm, design, {"note": "synthetic"})
    write_psf_stack(tmp_path / "psf.tif", stack)
    viewer = make_napari_viewer()
    layer = _open_one(viewer, tmp_path / "psf.tif")
    # scale: mean depth step and the SENSOR pixel pitch (um); z translated to the first depth, x/y centred
    np.testing.assert_allclose(layer.scale, (4.0, 6.5, 6.5), rtol=1e-12)
    np.testing.assert_allclose(layer.translate, (-3.0, -8 * 6.5, -6 * 6.5), rtol=1e-12)
    md = layer.metadata
    assert md["kind"] == "psf_stack"
    assert md["depths_m"] == list(DEPTHS)  # exact floats
    np.testing.assert_allclose(md["depths_um"], (-3.0, 0.0, 5.0), rtol=1e-12)
    assert (md["pixel_size_m"], md["magnification"], md["wavelength_m"]) == (6.5 * um, 8.96, 680 * nm)
    assert md["design"]["name"] == design.name and md["metadata"] == {"note": "synthetic"}
    np.testing.assert_array_equal(layer.data, stack.data.numpy())

    _save(viewer, layer, tmp_path / "again.tif")
    back = read_psf_stack(tmp_path / "again.tif")
    torch.testing.assert_close(back.data, stack.data, rtol=0, atol=0)
    assert back.depths == DEPTHS and back.pixel_size == stack.pixel_size
    assert (back.magnification, back.wavelength) == (stack.magnification, stack.wavelength)
    assert back.design == design and back.metadata == {"note": "synthetic"}


def test_light_field_and_volume_round_trip(make_napari_viewer, tmp_path, notes):
    image = LightFieldImage(_rand(20, 24, seed=1) * 1000, 6.5 * um, {"photons": 1e6})
    volume = Volume(_rand(3, 10, 8, seed=2), (4 * um, 0.5 * um, 0.5 * um), DEPTHS, {"phantom": "beads"})
    write_image(tmp_path / "lf.tif", image)
    write_volume(tmp_path / "vol.tif", volume)
    viewer = make_napari_viewer()
    lf, vol = _open_one(viewer, tmp_path / "lf.tif"), _open_one(viewer, tmp_path / "vol.tif")
    np.testing.assert_allclose(lf.scale, (6.5, 6.5), rtol=1e-12)
    np.testing.assert_allclose(vol.scale, (4.0, 0.5, 0.5), rtol=1e-12)
    np.testing.assert_allclose(vol.translate, (-3.0, -5 * 0.5, -4 * 0.5), rtol=1e-12)
    assert lf.metadata["kind"] == "light_field" and vol.metadata["kind"] == "volume"
    assert [str(u) for u in vol.units] == ["micrometer"] * 3

    _save(viewer, lf, tmp_path / "lf2.tif")
    _save(viewer, vol, tmp_path / "vol2.tif")
    lf2, vol2 = read_image(tmp_path / "lf2.tif"), read_volume(tmp_path / "vol2.tif")
    torch.testing.assert_close(lf2.data, image.data, rtol=0, atol=0)
    assert lf2.pixel_size == image.pixel_size and lf2.metadata == image.metadata
    torch.testing.assert_close(vol2.data, volume.data, rtol=0, atol=0)
    assert vol2.voxel_size == volume.voxel_size and vol2.depths == DEPTHS
    assert vol2.metadata == volume.metadata

    lf.scale = (5.0, 5.0)  # a display change: the file keeps the recorded sampling, with a warning
    _save(viewer, lf, tmp_path / "lf3.tif")
    assert read_image(tmp_path / "lf3.tif").pixel_size == image.pixel_size
    (warning,) = notes.warnings()
    assert "(5.0, 5.0)" in warning and "(6.5, 6.5)" in warning


def test_conventional_pattern_stack_is_a_5d_layer(make_napari_viewer, tmp_path):
    layout = ConventionalPatterns(
        pixels_per_lenslet=3, voxels_per_lenslet=3, reach=(0, 1, 0), lenslets=(4, 4)
    )
    stack = PSFStack(
        _rand(3, 3, 3, 15, 15, seed=3), (-2 * um, 0.0, 2 * um), 6.5 * um, 20.0, 525 * nm, None, {"note": "n"},
        patterns=layout,
    )  # fmt: skip
    write_psf_stack(tmp_path / "conv.tif", stack)
    viewer = make_napari_viewer()
    layer = _open_one(viewer, tmp_path / "conv.tif")
    assert layer.data.shape == (3, 3, 3, 15, 15)
    np.testing.assert_allclose(layer.scale, (1.0, 1.0, 2.0, 6.5, 6.5), rtol=1e-12)
    _save(viewer, layer, tmp_path / "conv2.tif")
    back = read_psf_stack(tmp_path / "conv2.tif")
    torch.testing.assert_close(back.data, stack.data, rtol=0, atol=0)
    assert back.patterns == layout and back.metadata == {"note": "n"} and back.depths == stack.depths


def test_plain_layer_is_written_from_its_scale_in_micrometres(make_napari_viewer, tmp_path):
    viewer = make_napari_viewer()
    layer = viewer.add_image(np.arange(12.0, dtype=np.float32).reshape(3, 4), scale=(2.5, 2.5), name="plain")
    _save(viewer, layer, tmp_path / "plain.tif")
    back = read_image(tmp_path / "plain.tif")
    assert back.pixel_size == pytest.approx(2.5 * um, rel=1e-12)
    np.testing.assert_array_equal(back.data.numpy(), layer.data)


def test_writer_refuses_non_square_pixels_with_a_notification(make_napari_viewer, tmp_path, notes):
    viewer = make_napari_viewer()
    layer = viewer.add_image(np.ones((3, 4), np.float32), scale=(1.0, 2.0), name="stretched")
    viewer.layers.selection = {layer}
    with pytest.warns(UserWarning, match="did not return any written paths"):
        assert viewer.layers.save(str(tmp_path / "s.tif"), selected=True, plugin=PLUGIN) == []
    assert any("non-square pixels" in m and "stretched" in m for m in notes.errors())
    assert not (tmp_path / "s.tif").exists()


def test_foreign_files_are_left_to_other_readers(tmp_path):
    tifffile.imwrite(tmp_path / "plain.tif", np.zeros((4, 5), np.uint16))
    tifffile.imwrite(tmp_path / "imagej.tif", np.zeros((2, 4, 5), np.float32), imagej=True)
    (tmp_path / "other.json").write_text(json.dumps({"schema_version": 1, "layers": []}))
    (tmp_path / "list.json").write_text("[1, 2]")
    (tmp_path / "broken.json").write_text("{not json")
    (tmp_path / "notes.txt").write_text("hello")
    for name in (
        "plain.tif",
        "imagej.tif",
        "other.json",
        "list.json",
        "broken.json",
        "notes.txt",
        "missing.tif",
    ):
        assert get_reader(str(tmp_path / name)) is None, name
    assert get_reader([str(tmp_path / "plain.tif"), str(tmp_path / "other.json")]) is None


def test_invalid_design_file_gives_a_notification_and_no_layer(make_napari_viewer, tmp_path, notes):
    text = json.loads(sample_design().model_dump_json())
    text["wavelength_nm"] = 0.525  # micrometres by mistake
    (tmp_path / "bad.json").write_text(json.dumps(text))
    viewer = make_napari_viewer()
    assert viewer.open(tmp_path / "bad.json", plugin=PLUGIN) == []
    assert len(viewer.layers) == 0
    (message,) = notes.errors()
    assert "bad.json" in message and "wavelength_nm" in message and "0.525" in message


def test_design_file_opens_as_a_psf_layer_computed_in_the_background(make_napari_viewer, qtbot, tmp_path):
    design = sample_design().updated(depths={"depth_range_um": (0.0, 10.0), "depth_step_um": 10.0})
    save_design(design, tmp_path / "two_depths.json")
    viewer = make_napari_viewer()
    assert viewer.open(tmp_path / "two_depths.json", plugin=PLUGIN) == []  # returns at once
    qtbot.waitUntil(lambda: not design_reader.running_jobs(), timeout=60_000)
    (layer,) = viewer.layers
    assert layer.name == "two_depths PSF" and layer.metadata["kind"] == "psf_stack"
    assert layer.metadata["depths_m"] == [0.0, 10 * um]
    np.testing.assert_allclose(layer.scale, (10.0, 6.5, 6.5), rtol=1e-12)
    # The reader computed it on a worker thread (its own intra-op thread count, so FFT sums in
    # another order): float32 rounding of the same model, not bit for bit.
    expected = simulate_psf(design).data.numpy()
    np.testing.assert_allclose(layer.data, expected, rtol=0, atol=1e-5 * float(np.abs(expected).max()))


class _ReentrantBar:
    """A progress bar whose update processes the job's queued ``ended`` (as napari's can)."""

    def __init__(self, on_update):
        self.total, self.n, self.closed, self.descriptions, self._on_update = 0, 0, False, [], on_update

    def update(self, step):
        self.n += step
        self._on_update()

    def set_description(self, text):
        self.descriptions.append(text)

    def close(self):
        self.closed = True


def test_progress_that_ends_the_job_while_updating_the_bar_is_not_an_error(qtbot, monkeypatch):
    # Seen on a loaded machine: the bar's update ran the queued end of the job, which closed the
    # bar; the progress handler then described a bar that no longer existed (AttributeError).
    job = design_reader.DesignPSFJob(sample_design(), "reentrant", viewer=qtbot)
    bar = _ReentrantBar(lambda: job._on_ended(design_reader.Outcome("cancelled")))
    monkeypatch.setattr(design_reader, "napari_progress", lambda **_: bar)
    monkeypatch.setattr(job.task, "start", lambda: None)
    job.start()
    job._on_progress(1, 4, "lenslet 1/4")
    assert bar.closed and bar.n == 1 and bar.descriptions == [] and job not in design_reader.running_jobs()
    job._on_progress(2, 4, "lenslet 2/4")  # a late one after the end: ignored
    assert bar.n == 1
