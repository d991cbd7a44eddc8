"""Reconstruct widget: the bead sample becomes a volume layer on the ground truth's grid; cancel and bad
input add nothing and say why."""

from __future__ import annotations

import inspect

import numpy as np
import pytest
from napari.layers import Layer
from qtpy.QtCore import Qt
from scipy import ndimage

from tests.napari.conftest import PLUGIN, add_layers


@pytest.fixture
def widget_on_sample(make_napari_viewer, bead_layers):
    viewer = make_napari_viewer()
    add_layers(viewer, bead_layers)
    _, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Reconstruct light field")
    return viewer, widget


def _wait(qtbot, widget, timeout=60_000):
    qtbot.waitUntil(lambda: not widget.busy, timeout=timeout)


def test_reconstruction_of_the_sample_finds_the_beads_on_the_truth_grid(widget_on_sample, qtbot, notes):
    viewer, widget = widget_on_sample
    assert widget.image_picker.currentText() == "beads light field"
    assert widget.psf_picker.currentText() == "beads PSF stack"
    assert widget.background.value() == 0.0  # the camera baseline comes from the image's metadata
    widget.set_method("rl")
    widget.iterations.setValue(10)
    assert widget.start()
    _wait(qtbot, widget)
    assert notes.errors() == []
    result = viewer.layers["beads light field rl"]
    truth = viewer.layers["beads ground truth"]
    assert result.data.shape == truth.data.shape == (5, 93, 93)
    np.testing.assert_allclose(result.scale, truth.scale, rtol=1e-12)
    np.testing.assert_allclose(result.translate, truth.translate, rtol=1e-12)
    assert result.metadata["kind"] == "volume"
    meta = result.metadata["metadata"]
    assert meta["iterations"] == 10 and meta["background"] == 0 and meta["units"] == "photons per voxel"
    assert meta["camera"]["baseline_adu"] == 100 and meta["camera"]["source"] == "image metadata"
    # photons per voxel, the truth's unit (docs/napari_plugin.md): the totals agree (measured 1.05
    # after 10 iterations: the dim edge voxels still hold a little), where a truth in bead units summed
    # to 8, 1.6e6 times less
    assert truth.metadata["metadata"]["units"] == meta["units"]
    assert 0.9 < float(result.data.sum()) / float(truth.data.sum()) < 1.1
    # the light concentrates on the beads: within 2 voxels (same depth) of a bead, 0.5 % of the volume,
    # lies > 25 % of the energy after 10 RL iterations (measured 38 %; a uniform volume would give 0.5 %)
    near = ndimage.binary_dilation(truth.data > 0, structure=np.ones((1, 5, 5)))
    assert near.mean() < 0.01
    assert result.data[near].sum() / result.data.sum() > 0.25
    for z, y, x in np.argwhere(truth.data > 0):  # each bead is a local peak (within one voxel)
        window = result.data[z, y - 3 : y + 4, x - 3 : x + 4] if 3 <= y < 90 and 3 <= x < 90 else None
        if window is not None:
            dy, dx = np.unravel_index(window.argmax(), window.shape)
            assert abs(dy - 3) <= 1 and abs(dx - 3) <= 1, (z, y, x)


def test_one_step_wiener_gives_a_volume_layer(widget_on_sample, qtbot):
    viewer, widget = widget_on_sample
    widget.set_method("wiener")
    assert not widget.iterations.isEnabled() and widget.snr.isEnabled()
    assert widget.start()
    _wait(qtbot, widget)
    layer = viewer.layers["beads light field wiener"]
    assert layer.metadata["metadata"]["snr"] == 100.0 and "iterations" not in layer.metadata["metadata"]


def test_the_view_is_fitted_to_the_new_volume(widget_on_sample, qtbot):
    """The volume is in object space, about 28 times smaller than the camera-space layers (+-34 um
    against +-936 um): after napari's reset it filled 3.6 % of the canvas (a black screenshot)."""
    viewer, widget = widget_on_sample
    if "layers" not in inspect.signature(viewer.fit_to_view).parameters:
        pytest.skip("this napari cannot fit the view to some layers (fit_to_view(layers=...))")
    camera = viewer.scene.camera if hasattr(viewer, "scene") else viewer.camera  # napari 0.9 moved it
    viewer.reset_view()  # fitted to every layer: the camera image and the PSF
    everything = camera.zoom
    widget.set_method("wiener")
    assert widget.start()
    _wait(qtbot, widget)
    layer = viewer.layers["beads light field wiener"]
    zoom, center = camera.zoom, tuple(camera.center)
    assert zoom > 20 * everything, (zoom, everything)
    viewer.fit_to_view(layers=[layer])  # what the widget did: fitting again changes nothing
    assert camera.zoom == pytest.approx(zoom, rel=1e-9)
    np.testing.assert_allclose(camera.center, center, atol=1e-9)


def test_the_view_is_left_alone_beside_a_layer_of_more_dimensions(make_napari_viewer):
    """napari fits a subset by indexing the viewer's displayed axes into the subset's extent: with a
    5-D layer (a conventional pattern stack) in the viewer a 3-D volume raised IndexError there."""
    from lfm_studio.napari_plugin.reconstruct_widget import fit_view_to

    viewer = make_napari_viewer()
    viewer.add_image(np.zeros((2, 2, 3, 8, 8), np.float32), name="patterns")
    volume = viewer.add_image(np.zeros((3, 4, 4), np.float32), name="volume")
    camera = viewer.scene.camera if hasattr(viewer, "scene") else viewer.camera
    before = (camera.zoom, tuple(camera.center))
    assert not fit_view_to(viewer, volume)
    assert (camera.zoom, tuple(camera.center)) == before


def test_cancel_leaves_no_half_layer(widget_on_sample, qtbot, notes):
    viewer, widget = widget_on_sample
    before = [(layer.name, id(layer)) for layer in viewer.layers]
    widget.iterations.setValue(5000)
    assert widget.start()
    qtbot.waitUntil(lambda: widget.controls.bar.value() >= 1, timeout=60_000)  # iterating
    widget.cancel()
    _wait(qtbot, widget)
    assert [(layer.name, id(layer)) for layer in viewer.layers] == before
    assert widget.controls.bar.value() < 5000
    assert any("cancelled" in m for m in notes.infos())
    assert widget.controls.run_button.isEnabled()


def test_mismatched_pixel_sizes_are_refused_with_a_notification(widget_on_sample, notes):
    viewer, widget = widget_on_sample
    lf = viewer.layers["beads light field"]
    widget.background.setValue(42.0)
    binned = viewer.add_image(lf.data[::2, ::2], scale=(13.0, 13.0), name="binned frame")
    # a new layer refreshes the pickers but keeps their choices and the user's background
    assert widget.psf_picker.currentText() == "beads PSF stack" and widget.background.value() == 42.0
    widget.image_picker.set_layer(binned)
    count = len(viewer.layers)
    assert not widget.start()
    assert not widget.busy and len(viewer.layers) == count
    (message,) = notes.errors()
    for part in (
        "pixel size does not match",
        "'binned frame'",
        "13 um",
        "'beads PSF stack'",
        "6.5 um",
        "Fix:",
    ):
        assert part in message


def test_missing_psf_layer_is_refused_with_a_notification(make_napari_viewer, notes):
    viewer = make_napari_viewer()
    viewer.add_image(np.zeros((8, 8), np.float32), name="frame")
    _, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Reconstruct light field")
    assert not widget.start()
    (message,) = notes.errors()
    assert "No PSF stack layer" in message and "Simulate PSF" in message


def test_a_registered_method_is_offered_with_its_options_and_runs(
    make_napari_viewer, bead_layers, qtbot, notes
):
    from lfm_studio.engine.image_quality import ncc
    from tests import toy_method

    with toy_method.registered():
        viewer = make_napari_viewer()
        add_layers(viewer, bead_layers)
        _, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Reconstruct light field")
        offered = [widget.method.itemData(i) for i in range(widget.method.count())]
        assert offered[:4] == ["rl", "rl-accelerated", "wiener", "tikhonov"] and "backprojection" in offered
        widget.set_method("backprojection")
        scale = widget.option_field("scale")
        assert scale.isEnabled() and scale.value() == 1.0
        assert not widget.iterations.isEnabled() and not widget.snr.isEnabled()
        scale.setValue(2.0)
        assert widget.start()
        _wait(qtbot, widget)
    assert notes.errors() == []
    layer = viewer.layers["beads light field backprojection"]
    meta = layer.metadata["metadata"]
    assert meta["method"] == "backprojection" and meta["scale"] == 2.0
    truth = viewer.layers["beads ground truth"].data
    assert float(ncc(np.asarray(truth), np.asarray(layer.data))) > 0.1  # a constant volume scores 0


def test_a_conventional_pattern_stack_disables_wiener_with_the_reason(widget_on_sample):
    """A 5-D pattern stack cannot be reconstructed by Wiener (shift-invariant OTFs only): the method
    box greys it out with the reason, as the studio does, instead of failing after Reconstruct."""
    import torch

    from lfm_studio.engine.psf_stack import ConventionalPatterns, PSFStack
    from lfm_studio.engine.units import nm, um
    from lfm_studio.napari_plugin.layer_data import psf_layer_data

    viewer, widget = widget_on_sample
    box = widget.options.method
    wiener = box.findData("wiener")
    widget.set_method("wiener")
    assert box.model().item(wiener).isEnabled()  # the sample's PSF is shift-invariant
    layout = ConventionalPatterns(
        pixels_per_lenslet=3, voxels_per_lenslet=3, reach=(0, 0, 0), lenslets=(2, 2)
    )
    stack = PSFStack(
        torch.ones(3, 3, 3, 9, 9), (-1 * um, 0.0, 1 * um), 6.5 * um, 10.0, 525 * nm, patterns=layout
    )
    patterns = viewer.add_layer(Layer.create(*psf_layer_data(stack, name="patterns")))
    widget.psf_picker.set_layer(patterns)
    assert not box.model().item(wiener).isEnabled()
    assert "needs a laterally shift-invariant" in box.itemData(wiener, Qt.ItemDataRole.ToolTipRole)
    assert widget.options.method_name() != "wiener"  # the chosen Wiener was replaced by one that fits
    widget.psf_picker.set_layer(viewer.layers["beads PSF stack"])
    assert box.model().item(wiener).isEnabled()
