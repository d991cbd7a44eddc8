"""MLA editor dock: edits the lenslets of a PSF layer's design, saves it without overwriting, recomputes the layer."""

from __future__ import annotations

import numpy as np

from lfm_studio.engine.design import load_design
from tests.napari.conftest import PLUGIN, add_layers


def test_dock_opens_on_a_preset(make_napari_viewer):
    viewer = make_napari_viewer()
    _, dock = viewer.window.add_plugin_dock_widget(PLUGIN, "MLA editor")
    assert dock.design is not None
    assert len(dock.editor.lenslets()) == dock.design.mla.count
    dock.set_preset("lfm_prevedel2014")  # a regular grid: shown, not editable here
    assert not dock.editor.isEnabled() and "regular lenslet grid" in dock.status.text()


def test_edit_save_and_recompute_the_psf_layer(make_napari_viewer, qtbot, bead_layers, tmp_path, notes):
    viewer = make_napari_viewer()
    add_layers(viewer, bead_layers)
    psf_layer = viewer.layers["beads PSF stack"]
    _, dock = viewer.window.add_plugin_dock_widget(PLUGIN, "MLA editor")
    viewer.layers.selection.active = psf_layer
    assert dock.use_selected_layer()
    assert dock.design.name.endswith("(sample: 288 px camera)") and dock.design.mla.count == 9

    centre = next(i for i, lens in enumerate(dock.editor.lenslets()) if lens.center_um == (0.0, 0.0))
    dock.editor.set_selection([centre])
    assert dock.editor.delete_selected()
    assert dock.design.mla.count == 8
    assert all(lens.center_um != (0.0, 0.0) for lens in dock.design.mla.lenslets)

    path = tmp_path / "eight.json"
    assert dock.save_design_as(path)
    assert load_design(path) == dock.design
    saved = path.read_bytes()
    assert not dock.save_design_as(path)  # never overwrites unasked
    assert path.read_bytes() == saved
    assert any("already exists" in m for m in notes.errors())

    middle = (slice(None), slice(144 - 40, 144 + 41), slice(144 - 40, 144 + 41))  # the central sub-image
    before = psf_layer.data[middle].sum()
    assert dock.recompute()
    qtbot.waitUntil(lambda: not dock.busy, timeout=60_000)
    assert viewer.layers["beads PSF stack"] is psf_layer  # replaced in place, not added
    assert notes.errors()[1:] == []
    assert len(psf_layer.metadata["design"]["mla"]["lenslets"]) == 8
    # without the central lenslet its sub-image is dark (what remains, 0.75 %, is the defocused
    # neighbours' light spilling in); the corner sub-image is unchanged
    assert psf_layer.data[middle].sum() < 0.02 * before
    corner = (slice(None), slice(0, 100), slice(0, 100))
    old = bead_layers[1][0][corner]
    change = np.abs(psf_layer.data[corner] - old).max() / old.max()
    assert change < 1e-3, change


def test_a_refused_edit_shows_the_designs_sentence_without_pydantic_wrapping(make_napari_viewer, notes):
    viewer = make_napari_viewer()
    _, dock = viewer.window.add_plugin_dock_widget(PLUGIN, "MLA editor")
    dock.set_preset("flfm_guo2019")
    before = dock.design
    lenslets = list(dock.editor.lenslets())
    lenslets[0] = lenslets[0].model_copy(update={"center_um": (3000.0, 0.0)})  # beyond the pupil image
    dock.editor.lensletsCommitted.emit(tuple(lenslets))
    assert dock.design is before  # the last valid design is kept
    (message,) = notes.errors()
    assert message.startswith(
        "Lenslet edit not applied to the design: lenslet centres must lie inside the pupil"
    )
    assert dock.status.text().startswith("Refused: lenslet centres must lie inside the pupil")
    for text in (message, dock.status.text()):
        for boilerplate in ("validation error for", "[type=", "input_value", "errors.pydantic.dev"):
            assert boilerplate not in text, text
