"""A learned checkpoint applied in napari: the Reconstruct dock's "learned" method on the bead sample's
light-field and PSF layers gives a volume layer; a checkpoint for another design is an error
notification, not a traceback, and adds no layer."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lfm_studio.engine.image_quality import ncc
from lfm_studio.engine.learned import stack_identity, train
from lfm_studio.engine.simulation import design_depths, imaging_setup, simulate_psf
from lfm_studio.napari_plugin.layer_data import stack_from_layer
from lfm_studio.napari_plugin.sample_data import sample_design
from tests.napari.conftest import PLUGIN, add_layers


@pytest.fixture(autouse=True)
def _one_torch_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _train(stack, path, steps=3):
    """A tiny checkpoint for ``stack`` (the engine's train, as ``lfm-studio train --psf`` runs it)."""
    design_hash, depths = stack_identity(stack)
    train(imaging_setup(stack), max_steps=steps, design_hash=design_hash, depths=depths, checkpoint=path,
          threads=1)  # fmt: skip
    return path


@pytest.fixture
def widget_on_sample(make_napari_viewer, bead_layers):
    viewer = make_napari_viewer()
    add_layers(viewer, bead_layers)
    _, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Reconstruct light field")
    return viewer, widget


def _psf_of(viewer):
    layer = viewer.layers["beads PSF stack"]
    return stack_from_layer(layer.data, layer.metadata, name=layer.name)


def test_a_checkpoint_for_the_sample_gives_a_volume_layer_on_the_truth_grid(widget_on_sample, qtbot, notes,
                                                                            tmp_path):  # fmt: skip
    viewer, widget = widget_on_sample
    model = _train(_psf_of(viewer), tmp_path / "sample.safetensors")
    widget.set_method("learned")
    widget.option_field("model").setValue(str(model))
    assert widget.start()
    qtbot.waitUntil(lambda: not widget.busy, timeout=300_000)
    assert notes.errors() == []
    result, truth = viewer.layers["beads light field learned"], viewer.layers["beads ground truth"]
    assert result.data.shape == truth.data.shape
    np.testing.assert_allclose(result.scale, truth.scale, rtol=1e-12)
    volume = np.asarray(result.data, dtype=np.float64)
    assert np.isfinite(volume).all() and volume.std() > 0  # not constant
    # A 3-step model is far from converged but already correlates with the beads (0 = unrelated).
    assert (
        float(ncc(torch.as_tensor(np.asarray(truth.data, dtype=np.float64)), torch.as_tensor(volume))) > 0.05
    )


def test_a_checkpoint_for_another_design_is_a_notification_not_a_traceback(widget_on_sample, qtbot, notes,
                                                                           tmp_path):  # fmt: skip
    viewer, widget = widget_on_sample
    design = sample_design()
    other = simulate_psf(design, depths=design_depths(design)[:3])  # 3 depths, not the sample's
    model = _train(other, tmp_path / "other.safetensors", steps=1)
    before = [layer.name for layer in viewer.layers]
    widget.set_method("learned")
    widget.option_field("model").setValue(str(model))
    widget.start()
    qtbot.waitUntil(lambda: not widget.busy, timeout=300_000)
    assert [layer.name for layer in viewer.layers] == before
    errors = notes.errors()
    assert len(errors) == 1 and "other.safetensors" in errors[0] and "Traceback" not in errors[0], errors
