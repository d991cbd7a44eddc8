"""Calibration in the napari plugin: the reader shows the fitted lenslet grid with its residuals; the
Reconstruct widget reconstructs a misaligned raw frame with the calibration (issue 21).

Scene: :func:`lfm_studio.engine.calibration.synthetic_scene.misaligned_bead_scene` (beads seen
through 19.37 x 19.31 px lenslets rotated 1.5 deg, vignetting, noise, dark offset, hot pixels).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from napari.layers import Layer

from lfm_studio.engine.calibration import calibrate, save_calibration
from lfm_studio.engine.calibration.synthetic_scene import misaligned_bead_scene
from lfm_studio.napari_plugin import calibration_reader
from lfm_studio.napari_plugin.layer_data import psf_layer_data
from lfm_studio.napari_plugin.reader import get_reader
from tests.napari.conftest import PLUGIN


@pytest.fixture(scope="module")
def scene():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield misaligned_bead_scene()
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def calibration_file(scene, tmp_path_factory):
    path = tmp_path_factory.mktemp("napari_calibration") / "calib.json"
    save_calibration(calibrate(scene.radiometry, scene.nominal, dark=scene.dark), path)
    return path


def test_reader_opens_a_calibration_as_the_fitted_grid_with_residuals(
    scene, calibration_file, make_napari_viewer
):
    assert get_reader(str(calibration_file)) is calibration_reader.read_calibration
    viewer = make_napari_viewer()
    layers = viewer.open(str(calibration_file), plugin=PLUGIN)
    assert [layer.name for layer in layers] == ["calib fitted grid", "calib measured centres"]
    grid, measured = layers
    assert grid.metadata["kind"] == "calibration" and grid.metadata["source"] == str(calibration_file)
    features = grid.features
    assert len(features) == len(grid.data) == len(measured.data) > 50
    # The fitted points lie on the true lattice (independent truth), within 0.05 px.
    ij = torch.from_numpy(scene.lattice.lattice_coordinates(torch.from_numpy(grid.data)).round().numpy())
    truth = scene.lattice.centres(ij).numpy()
    assert np.abs(grid.data - truth).max() < 0.05
    # The residual feature is the distance between the measured centre and the fitted site.
    np.testing.assert_allclose(
        features["residual_px"], np.linalg.norm(measured.data - grid.data, axis=1), rtol=1e-6, atol=1e-6
    )
    np.testing.assert_array_equal(features[["measured_y_px", "measured_x_px"]].to_numpy(), measured.data)
    # Flagged lenslets: named flags, not used, red; the used ones fit to 0.1 px and are green.
    used = features["used"].to_numpy(dtype=bool)
    assert (features["flags"][~used] != "").all() and (features["flags"][used] == "").all()
    assert 0 < (~used).sum() < used.sum()
    names = {name for flags in features["flags"] for name in flags.split(",") if name}
    assert names <= {"edge", "dim", "residual"} and "dim" in names
    lit = ~features["flags"].str.contains("dim").to_numpy(dtype=bool)
    inside = ((ij >= -4) & (ij < 4)).all(dim=1).numpy()  # the scene lights lenslets -4..3 x -4..3
    assert inside.sum() == 64 and lit[inside].all() and lit[~inside].sum() <= 2  # the dark rim is "dim"
    np.testing.assert_allclose(grid.face_color[used][:, :3], [[0, 1, 0]] * int(used.sum()))
    np.testing.assert_allclose(grid.face_color[~used][:, :3], [[1, 0, 0]] * int((~used).sum()))
    assert features["residual_px"][used].max() < 0.1


def test_reader_leaves_other_json_alone_and_names_a_bad_calibration(tmp_path, make_napari_viewer, notes):
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"format": "something else", "version": 1}))
    assert get_reader(str(other)) is None
    newer = tmp_path / "newer.json"
    newer.write_text(json.dumps({"format": "lfm_studio.calibration", "version": 99}))
    assert get_reader(str(newer)) is calibration_reader.read_calibration
    viewer = make_napari_viewer()
    assert calibration_reader.read_calibration(str(newer)) == [(None,)]
    assert len(viewer.layers) == 0
    assert any("could not open the calibration newer.json" in message for message in notes.errors())


def _pearson(a, b) -> float:
    a, b = np.asarray(a, dtype=np.float64).ravel(), np.asarray(b, dtype=np.float64).ravel()
    return float(np.corrcoef(a, b)[0, 1])


def test_reconstruct_widget_reconstructs_a_raw_frame_with_the_calibration(
    scene, calibration_file, make_napari_viewer, qtbot, notes
):
    viewer = make_napari_viewer()
    viewer.add_layer(Layer.create(*psf_layer_data(scene.stack, name="psf")))
    viewer.add_image(scene.raw.numpy(), name="raw")
    _, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Reconstruct light field")
    widget.image_picker.set_layer(viewer.layers["raw"])
    # Without the calibration, the raw frame (scale 1) does not fit the PSF: refused, named, nothing added.
    assert not widget.start()
    assert any("PSF pixel size does not match the image" in message for message in notes.errors())
    assert len(viewer.layers) == 2
    # Opening the calibration shows its grid and fills the widget's calibration field.
    viewer.open(str(calibration_file), plugin=PLUGIN)
    assert widget.calibration.text() == str(calibration_file)
    notes.clear()
    widget.set_method("rl-accelerated")
    assert widget.start()
    qtbot.waitUntil(lambda: not widget.busy, timeout=60_000)
    assert notes.errors() == []
    result = viewer.layers["raw rl-accelerated"]
    meta = result.metadata["metadata"]
    assert meta["calibration"] == "calib.json"
    assert meta["camera"]["baseline_adu"] == 0.0  # the dark frame was subtracted by the calibration, once
    assert result.data.shape == tuple(scene.truth.shape)
    score = _pearson(result.data, scene.truth)
    assert score > 0.85, (
        score
    )  # measured 0.950, as through the CLI (aligned case 0.976; uncalibrated crop 0.00)


def test_reconstruct_widget_names_a_missing_calibration_file(scene, make_napari_viewer, tmp_path, notes):
    viewer = make_napari_viewer()
    viewer.add_layer(Layer.create(*psf_layer_data(scene.stack, name="psf")))
    viewer.add_image(scene.raw.numpy(), name="raw")
    _, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Reconstruct light field")
    widget.set_calibration(tmp_path / "nope.json")
    assert not widget.start()
    assert any("nope.json" in message and "does not exist. Fix" in message for message in notes.errors())
