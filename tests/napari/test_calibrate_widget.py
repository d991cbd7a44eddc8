"""The Calibrate dock widget (issue 21): a synthetic misaligned radiometry frame -> the fitted grid overlay.

Frames: :func:`lfm_studio.engine.calibration.synthetic.synthetic_frames` (disks behind a
15.43 x 15.36 px lattice rotated 0.7 deg, off centre, vignetting, noise, dark offset, hot
pixels), calibrated against :func:`conventional_design_for` with the nominal 15.4 px pitch. The
lenslet at index (0, 0) is covered (its disk replaced by the dark frame), so exactly one is flagged.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import torch
from qtpy.QtWidgets import QFileDialog, QMessageBox

from lfm_studio.engine.calibration import LensletLattice, load_calibration
from lfm_studio.engine.calibration.calibration_io import calibration_files
from lfm_studio.engine.calibration.synthetic import conventional_design_for, synthetic_frames
from tests.napari.conftest import PLUGIN

SHAPE = (200, 216)
PITCH = (15.43, 15.36)
COVERED = (slice(93, 110), slice(98, 116))  # the disk of lenslet (0, 0), centred at (101.3, 106.8) px


@pytest.fixture(scope="module")
def frames():
    truth = LensletLattice.from_geometry(PITCH, math.radians(0.7), (101.3, 106.8))
    return synthetic_frames(SHAPE, truth, disk_diameter=13.8, seed=5)


@pytest.fixture(scope="module")
def design():
    return conventional_design_for(15.4, SHAPE)


@pytest.fixture
def widget_with_frames(frames, design, make_napari_viewer):
    viewer = make_napari_viewer()
    radiometry = frames.radiometry.clone()
    radiometry[COVERED] = frames.dark[COVERED]
    viewer.add_image(radiometry.numpy(), name="radiometry", scale=(0.5, 0.5), translate=(3.0, -2.0))
    viewer.add_image(frames.dark.numpy(), name="dark")
    _, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Calibrate")
    widget.radiometry_picker.set_layer(viewer.layers["radiometry"])
    widget.set_dark(viewer.layers["dark"])
    widget.set_design(design, "synthetic")
    return viewer, widget


def _finish(widget, qtbot) -> None:
    qtbot.waitUntil(lambda: not widget.busy, timeout=60_000)


def test_calibrates_a_misaligned_frame_into_the_fitted_grid_overlay(frames, widget_with_frames, qtbot, notes):
    viewer, widget = widget_with_frames
    assert not widget.save_button.isEnabled()
    assert widget.start()
    _finish(widget, qtbot)
    assert notes.errors() == []
    assert [layer.name for layer in viewer.layers] == [
        "radiometry",
        "dark",
        "radiometry fitted grid",
        "radiometry measured centres",
    ]
    grid, measured = viewer.layers["radiometry fitted grid"], viewer.layers["radiometry measured centres"]
    assert grid.metadata["kind"] == "calibration" and grid.metadata["source"] is None
    # Every fitted point lies on the true lattice (independent truth) within 0.05 px.
    ij = frames.lattice.lattice_coordinates(torch.from_numpy(grid.data)).round()
    assert len(grid.data) > 100
    assert np.abs(grid.data - frames.lattice.centres(ij).numpy()).max() < 0.05
    # The features carry the residuals: the distance between measured centre and fitted site.
    np.testing.assert_allclose(
        grid.features["residual_px"], np.linalg.norm(measured.data - grid.data, axis=1), atol=1e-6
    )
    # The overlay lies over the radiometry layer (its scale and translate).
    for layer in (grid, measured):
        np.testing.assert_allclose(layer.scale, [0.5, 0.5])
        np.testing.assert_allclose(layer.translate, [3.0, -2.0])
    # The covered lenslet, and only it, is flagged "dim".
    used = grid.features["used"].to_numpy(dtype=bool)
    assert ij[torch.from_numpy(~used)].tolist() == [[0.0, 0.0]]
    assert list(grid.features["flags"][~used]) == ["dim"]
    # The summary line: the pitch within 0.01 px of the truth, the rotation, the flagged count.
    line = widget.summary.text()
    found = re.search(
        r"pitch ([\d.]+) x ([\d.]+) px, rotation (-?[\d.]+) deg, RMS residual ([\d.]+) px, "
        r"(\d+) of (\d+) lenslets flagged",
        line,
    )
    assert found, line
    py, px, rotation, rms = (float(found.group(i)) for i in range(1, 5))
    assert abs(py - PITCH[0]) < 0.01 and abs(px - PITCH[1]) < 0.01, line
    assert abs(abs(rotation) - 0.7) < 0.05, line
    assert 0 < rms < 0.1, line
    assert int(found.group(5)) == 1 and int(found.group(6)) == len(grid.data)
    assert widget.save_button.isEnabled()


def test_cancel_adds_no_layer(widget_with_frames, qtbot, notes):
    viewer, widget = widget_with_frames
    assert widget.start()
    widget.cancel()
    _finish(widget, qtbot)
    assert len(viewer.layers) == 2
    assert widget.calibration is None and not widget.save_button.isEnabled()
    assert any("cancelled" in message for message in notes.infos())
    assert notes.errors() == []


def test_a_frame_without_a_grid_is_named_and_adds_no_layer(design, make_napari_viewer, qtbot, notes):
    viewer = make_napari_viewer()
    noise = 100.0 + 30.0 * torch.rand(SHAPE, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    viewer.add_image(noise.numpy(), name="noise")
    _, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Calibrate")
    widget.set_design(design, "synthetic")
    assert widget.start()
    _finish(widget, qtbot)
    assert len(viewer.layers) == 1 and widget.calibration is None
    errors = notes.errors()
    assert len(errors) == 1 and "Calibration failed" in errors[0], errors
    assert "no lenslet grid" in errors[0] and "Fix:" in errors[0]


def test_refuses_missing_input_before_starting(design, make_napari_viewer, notes):
    viewer = make_napari_viewer()
    _, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Calibrate")
    widget.set_design(design, "synthetic")
    assert not widget.start() and not widget.busy
    assert any("no radiometry image" in message and "Fix:" in message for message in notes.errors())
    viewer.add_image(np.zeros(SHAPE), name="radiometry")
    widget.use_dark.setChecked(True)
    widget.dark_picker.clear()  # a dark frame asked for, but none chosen
    assert not widget.start()
    assert any("no dark image layer" in message for message in notes.errors())
    assert len(viewer.layers) == 1


def test_save_writes_a_calibration_that_loads_and_fills_the_reconstruct_widget(
    frames, widget_with_frames, qtbot, notes, tmp_path, monkeypatch
):
    viewer, widget = widget_with_frames
    _, reconstruct = viewer.window.add_plugin_dock_widget(PLUGIN, "Reconstruct light field")
    assert widget.save(tmp_path / "early.json") is None  # nothing calibrated yet
    assert any("Nothing to save" in message for message in notes.errors())
    assert widget.start()
    _finish(widget, qtbot)
    path = tmp_path / "calib.json"
    assert widget.save(path) == path
    loaded = load_calibration(path)
    assert loaded.grid.lattice == widget.calibration.grid.lattice
    assert torch.allclose(loaded.dark_frame, frames.dark.float())
    assert reconstruct.calibration.text() == str(path)
    assert viewer.layers["radiometry fitted grid"].metadata["source"] == str(path)
    # No overwrite without asking: refused and named, the file is untouched.
    before = path.read_bytes()
    notes.clear()
    assert widget.save(path) is None
    assert any("already exists" in message and "Fix" in message for message in notes.errors())
    assert path.read_bytes() == before
    # The button asks first: "No" keeps the file, "Yes" replaces it (and the dark-frame file).
    monkeypatch.setattr(QFileDialog, "getSaveFileName", lambda *a, **k: (str(path), ""))
    path.write_text("{}")  # a marker: replaced only when the user agrees
    monkeypatch.setattr(QMessageBox, "question", lambda *a, **k: QMessageBox.StandardButton.No)
    widget.save_button.click()
    assert path.read_text() == "{}"
    monkeypatch.setattr(QMessageBox, "question", lambda *a, **k: QMessageBox.StandardButton.Yes)
    widget.save_button.click()
    assert load_calibration(path).grid.lattice == widget.calibration.grid.lattice
    assert [p.suffix for p in calibration_files(path)] == [".json", ".npz"]  # and its dark frame
