"""Simulate PSF widget: a design file becomes a PSF layer whose spots sit under the lenslets; bad designs
and cancel add nothing."""

from __future__ import annotations

import json

import numpy as np
from scipy import ndimage

from lfm_studio.engine.design import save_design
from lfm_studio.engine.units import um
from lfm_studio.napari_plugin.sample_data import sample_design
from tests.napari.conftest import PLUGIN


def _simulate_widget(make_napari_viewer):
    viewer = make_napari_viewer()
    _, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Simulate PSF")
    return viewer, widget


def test_design_file_to_psf_layer_with_spots_under_the_lenslets(make_napari_viewer, qtbot, tmp_path, notes):
    design = sample_design()
    save_design(design, tmp_path / "flfm.json")
    viewer, widget = _simulate_widget(make_napari_viewer)
    assert widget.load_design_file(tmp_path / "flfm.json")
    widget.set_depths_um(-10.0, 10.0, 10.0)
    assert widget.start()
    qtbot.waitUntil(lambda: not widget.busy, timeout=60_000)
    assert notes.errors() == []
    (layer,) = viewer.layers
    assert layer.metadata["kind"] == "psf_stack" and layer.name == f"PSF {design.name}"
    assert layer.metadata["depths_m"] == [-10 * um, 0.0, 10 * um]
    assert layer.metadata["design"]["depths"] == {"depth_range_um": [-10.0, 10.0], "depth_step_um": 10.0}
    np.testing.assert_allclose(layer.scale, (10.0, 6.5, 6.5), rtol=1e-12)
    # geometric optics: a point on the native focal plane gives one spot per lenslet at the lenslet's
    # centre on the sensor (Fourier LFM, camera at the lenslet focal plane): within half a pixel
    focus = layer.data[1]
    peaks = np.argwhere((focus == ndimage.maximum_filter(focus, size=31)) & (focus > 0.1 * focus.max()))
    centre = np.array(focus.shape) // 2
    found = sorted(map(tuple, (peaks - centre) * 6.5))  # (y, x) um from the axis
    lenslets = sorted(
        (lens["center_um"][1], lens["center_um"][0])
        for lens in json.loads(design.model_dump_json())["mla"]["lenslets"]
    )
    assert len(found) == len(lenslets) == 9
    np.testing.assert_allclose(found, lenslets, atol=0.5 * 6.5)


def test_invalid_design_file_is_refused_with_a_notification(make_napari_viewer, tmp_path, notes):
    text = json.loads(sample_design().model_dump_json())
    text["objective"]["numerical_aperture"] = 1.2  # above the immersion index 1.0 (air)
    (tmp_path / "bad.json").write_text(json.dumps(text))
    _, widget = _simulate_widget(make_napari_viewer)
    before = widget.design
    assert not widget.load_design_file(tmp_path / "bad.json")
    assert widget.design is before
    (message,) = notes.errors()
    assert "bad.json" in message and "numerical_aperture" in message and "1.2" in message


def test_invalid_depth_range_is_refused_and_cancel_adds_nothing(make_napari_viewer, qtbot, notes):
    viewer, widget = _simulate_widget(make_napari_viewer)
    widget.set_design(sample_design())
    widget.set_depths_um(10.0, -10.0, 5.0)  # stop before start
    assert not widget.start()
    (message,) = notes.errors()
    # the design's own sentence, without pydantic's "1 validation error for Design ... [type=value_error"
    assert (
        message
        == "Cannot simulate: depth_range_um must be ordered (start <= stop); got (10, -10) um. Fix: write (-10, 10)."
    )
    widget.set_depths_um(-40.0, 40.0, 1.0)  # 81 depths: long enough to cancel
    assert widget.start()
    qtbot.waitUntil(
        lambda: widget.controls.bar.maximum() > 1 and widget.controls.bar.value() >= 1, timeout=60_000
    )
    widget.cancel()
    qtbot.waitUntil(lambda: not widget.busy, timeout=60_000)
    assert len(viewer.layers) == 0
    assert any("cancelled" in m for m in notes.infos())


def test_the_summary_line_counts_the_depths_that_will_be_simulated(make_napari_viewer):
    _, widget = _simulate_widget(make_napari_viewer)
    widget.set_design(sample_design(), "sample")  # 5 depths, -20 to 20 um
    assert widget.summary.text() == "sample: fourier LFM, 288 x 288 px camera, 5 depths, 9 lenslets"
    widget.set_depths_um(-10.0, 10.0, 10.0)
    assert (
        widget.summary.text()
        == "sample: fourier LFM, 288 x 288 px camera, 3 depths, -10 to 10 um, 9 lenslets"
    )
    widget.depth_step.setValue(4.0)  # the last depth on the grid below the stop
    assert "6 depths, -10 to 10 um" in widget.summary.text()
    widget.depth_step.setValue(3.0)
    assert "7 depths, -10 to 8 um" in widget.summary.text()
    widget.set_depths_um(10.0, -10.0, 5.0)
    assert "other depths refused (depth_range_um must be ordered (start <= stop)" in widget.summary.text()
    widget.custom_depths.setChecked(False)  # back to the design's depths
    assert widget.summary.text() == "sample: fourier LFM, 288 x 288 px camera, 5 depths, 9 lenslets"
