"""PSFViewer: layers in micrometres, in-place updates, non-blank renders, the fallback, clean close."""

from __future__ import annotations

import threading
import weakref

import numpy as np
import pytest
import torch
from qtpy.QtGui import QGuiApplication
from qtpy.QtWidgets import QApplication

from lfm_studio.engine.psf_stack import ConventionalPatterns, PSFStack
from lfm_studio.widgets import psf_viewer
from lfm_studio.widgets.psf_viewer import PSFViewer
from lfm_studio.widgets.viewer import napari_embed
from lfm_studio.widgets.viewer.display_data import psf_display, pyramid_levels
from tests.ui.conftest import collect_widgets

PITCH, MAG = 6.5e-6, 8.96
DEPTHS = (-20e-6, 0.0, 20e-6)
SPOT = (16, 44)  # (row, column) of the bright spot in a 64 x 64 slice: up and right of the axis


def spot_stack(depths=DEPTHS, n=64, *, lead=(), patterns=None) -> PSFStack:
    """One Gaussian spot per depth, wider away from focus, at SPOT (rows/cols of an n x n slice);
    ``patterns``: the typed layout of conventional lenslet patterns (``lead`` = (S, S))."""
    yy, xx = torch.meshgrid(
        torch.arange(n, dtype=torch.float32), torch.arange(n, dtype=torch.float32), indexing="ij"
    )
    r2 = (yy - SPOT[0]) ** 2 + (xx - SPOT[1]) ** 2
    planes = [torch.exp(-r2 / (2 * (1.5 + abs(z) * 1e5) ** 2)) for z in depths]
    data = torch.stack(planes).expand(*lead, len(depths), n, n).contiguous()
    return PSFStack(data, depths, PITCH, MAG, 680e-9, patterns=patterns)


def settle(qtbot, ms=400):
    qtbot.wait(ms)  # several frames: vispy draws on the event loop


@pytest.fixture
def viewer(qtbot):
    reason = napari_embed.napari_unavailable_reason()
    if reason is not None and QGuiApplication.platformName() in ("offscreen", "minimal"):
        pytest.skip(f"napari canvas needs a display (run under pytest-xvfb): {reason}")
    view = PSFViewer(use_napari=True)
    qtbot.addWidget(view)
    view.resize(640, 480)
    yield view
    view.close_viewer()


def test_show_psf_gives_a_layer_in_sensor_micrometres(viewer):
    viewer.show_psf(spot_stack())
    layer = viewer.layer("PSF")
    assert viewer.backend == "napari" and viewer.layer_names() == ["PSF"]
    # Depth step 20 um (sample side), lateral = sensor pitch 6.5 um: exact unit conversions.
    np.testing.assert_allclose(layer.scale, (20.0, 6.5, 6.5), rtol=1e-12)
    np.testing.assert_allclose(layer.translate, (-20.0, -32 * 6.5, -32 * 6.5), rtol=1e-12)
    assert [str(u) for u in layer.units] == ["micrometer"] * 3
    assert layer.metadata["space"] == "sensor" and "sensor pixel pitch" in layer.metadata["lateral"]
    assert layer.metadata["sample_pixel_size_um"] == pytest.approx(6.5 / MAG, rel=1e-12)
    assert layer.metadata["depths_um"] == pytest.approx([-20.0, 0.0, 20.0], abs=1e-9)
    # 3 depths x 20 um against 64 x 6.5 um laterally: under 1/4, so the depth axis is drawn stretched.
    stretch = layer.metadata["z_stretch"]
    assert stretch > 1 and layer.affine.affine_matrix[0, 0] == pytest.approx(stretch)
    np.testing.assert_array_equal(layer.data, spot_stack().data.numpy())
    # Fixed 0.1-99.9 % limits over the stack with gamma 0.5 (sparse PSFs); slider over the whole range.
    low, high = np.percentile(spot_stack().data.numpy(), [0.1, 99.9])
    assert not layer.auto_contrast and layer.gamma == pytest.approx(0.5)
    np.testing.assert_allclose(layer.contrast_limits, (low, high), rtol=1e-5)
    assert high < 0.99 and layer.contrast_limits_range[1] == pytest.approx(1.0)


def test_showing_the_same_name_again_updates_the_layer_in_place(viewer):
    viewer.show_psf(spot_stack())
    layer = viewer.layer("PSF")
    model = viewer._scene.model
    inserted, removed = [], []
    model.layers.events.inserted.connect(inserted.append)
    model.layers.events.removed.connect(removed.append)
    full = spot_stack(depths=(-30e-6, -15e-6, 0.0, 15e-6, 30e-6))
    viewer.show_psf(full)
    assert viewer.layer("PSF") is layer and not inserted and not removed
    assert layer.data.shape == (5, 64, 64)
    np.testing.assert_allclose(layer.scale[0], 15.0, rtol=1e-12)
    np.testing.assert_allclose(layer.translate[0], -30.0, rtol=1e-12)
    np.testing.assert_array_equal(layer.data, full.data.numpy())


def test_conventional_patterns_are_5d_at_the_central_sub_position(viewer):
    layout = ConventionalPatterns(
        pixels_per_lenslet=5, voxels_per_lenslet=3, reach=(2, 0, 2), lenslets=(4, 4)
    )
    viewer.show_psf(spot_stack(n=65, lead=(3, 3), patterns=layout))  # (odd: patterns are centred)
    layer = viewer.layer("PSF")
    assert layer.ndim == 5 and layer.axis_labels[:2] == ("sub-position row", "sub-position column")
    assert viewer._scene.model.dims.current_step[:2] == (1, 1)
    np.testing.assert_allclose(layer.scale, (1, 1, 20.0, 6.5, 6.5), rtol=1e-12)


def test_image_and_volume_layers_live_in_their_own_space(viewer):
    viewer.show_psf(spot_stack())
    viewer.show_image(torch.rand(32, 48) * 100 + 100, 6.5e-6)
    viewer.show_volume(torch.rand(5, 16, 16), (torch.tensor(2e-6), np.float32(0.5e-6), 0.5e-6))
    image, volume = viewer.layer("light field"), viewer.layer("reconstruction")
    np.testing.assert_allclose(image.scale, (6.5, 6.5), rtol=1e-12)
    # rtol 1e-6: the voxel sizes were given as float32 scalars (eps 6e-8), the rest is exact.
    np.testing.assert_allclose(volume.scale, (2.0, 0.5, 0.5), rtol=1e-6)
    np.testing.assert_allclose(volume.translate, (-4.0, -4.0, -4.0), rtol=1e-6)  # centred: -(n // 2) * d
    assert image.colormap.name == "gray" and volume.colormap.name == "inferno"
    assert 100 <= image.contrast_limits[0] < image.contrast_limits[1] <= 200
    assert viewer.layer_names() == ["PSF", "light field", "reconstruction"]
    attached = [layer.name for layer in viewer._scene.model.layers]
    assert attached == ["reconstruction"]  # sample space only: its sliders span the volume alone
    viewer.focus("light field")
    assert [layer.name for layer in viewer._scene.model.layers] == ["PSF", "light field"]
    assert viewer.layer("light field").visible and not viewer.layer("PSF").visible
    viewer.show_psf(spot_stack())  # an update does not steal the focus
    assert viewer._scene.focused == "light field"


def test_bad_input_is_refused_with_the_parameter_named(viewer):
    with pytest.raises(ValueError, match="pixel_size_m"):
        viewer.show_image(torch.ones(8, 8), 0.0)
    with pytest.raises(ValueError, match="voxel_size_m"):
        viewer.show_volume(torch.ones(2, 8, 8), (1e-6, -1e-6, 1e-6))
    with pytest.raises(TypeError, match="complex"):
        viewer.show_image(torch.ones(8, 8, dtype=torch.complex64), 1e-6)


def _rgb(shot: np.ndarray) -> np.ndarray:
    return shot[..., :3].astype(np.float64)


def hide_overlays(viewer):
    """Text read-out and scale bar off, so only the data can make the canvas non-black."""
    overlays = viewer._scene.model.canvas.overlays
    overlays.text.visible = overlays.scale_bar.visible = False


def test_canvas_renders_the_psf_non_blank_and_the_right_way_up(viewer, qtbot):
    viewer.show()
    qtbot.waitExposed(viewer)
    viewer.show_psf(spot_stack())
    hide_overlays(viewer)
    settle(qtbot)
    shot = _rgb(viewer.screenshot())
    assert shot.var() > 0 and shot.max() > 100, "canvas is blank or all black"
    # The spot (row 16, col 44 of 64) must be drawn up and to the right of the canvas centre.
    luminance = shot.sum(axis=-1)
    row, col = np.unravel_index(np.argmax(luminance), luminance.shape)
    height, width = luminance.shape
    assert row < height / 2 and col > width / 2, (row, col, luminance.shape)


def test_3d_render_is_non_blank(viewer, qtbot):
    viewer.show()
    qtbot.waitExposed(viewer)
    viewer.show_psf(spot_stack())
    hide_overlays(viewer)
    viewer.set_3d(True)
    settle(qtbot, 600)
    assert viewer.is_3d() and viewer._button_3d.isChecked()
    shot = _rgb(viewer.screenshot())
    assert shot.var() > 0 and shot.max() > 100
    assert viewer.layer("PSF").bounding_box.visible
    viewer.set_3d(False)
    assert not viewer.layer("PSF").bounding_box.visible


def test_large_stacks_become_multiscale_layers_over_a_max_pooled_pyramid(qtbot):
    view = PSFViewer(use_napari=True, max_voxels_3d=3 * 16 * 16)
    qtbot.addWidget(view)
    stack = spot_stack()
    view.show_psf(stack)
    layer = view.layer("PSF")
    # 3 x 64 x 64 over a 3-D budget of 3 x 16 x 16: levels pooled 2x and 4x laterally.
    assert layer.multiscale and [level.shape for level in layer.data] == [
        (3, 64, 64),
        (3, 32, 32),
        (3, 16, 16),
    ]
    np.testing.assert_array_equal(np.asarray(layer.data[0]), stack.data.numpy())  # level 0 is the data
    np.testing.assert_allclose(layer.downsample_factors[-1], (1, 4, 4))
    np.testing.assert_allclose(layer.scale, (20.0, 6.5, 6.5), rtol=1e-12)  # physical scale of level 0
    assert np.asarray(layer.data[-1]).max() == pytest.approx(float(stack.data.max()))  # max keeps the peak
    view.set_3d(True)
    assert view._scene.drawn_factor("PSF") == 4  # napari renders the coarsest level in 3-D
    view.set_3d(False)
    assert view._scene.drawn_factor("PSF") == 1
    view.close_viewer()


def test_pyramid_levels_keep_small_data_and_pool_big_data_by_max():
    assert pyramid_levels(np.zeros((2, 8, 8), np.float32), max_voxels_3d=2 * 8 * 8) == ()
    big = np.zeros((2, 9, 9), np.float32)
    big[1, 8, 8] = 5.0
    levels = pyramid_levels(big, max_voxels_3d=2 * 3 * 3)
    assert [level.shape for level in levels] == [(2, 5, 5), (2, 3, 3)]  # ceil: the edge pixel is kept
    assert levels[0][1, 4, 4] == 5.0 and levels[1][1, 2, 2] == 5.0 and levels[1].sum() == 5.0
    # Lateral size alone also pools (about a canvas width): 2048 -> 1024 -> 512.
    assert [lv.shape for lv in pyramid_levels(np.zeros((2048, 2048), np.float32))] == [
        (1024, 1024),
        (512, 512),
    ]


def test_unsorted_depths_are_shown_in_depth_order():
    stack = spot_stack(depths=(20e-6, -20e-6, 0.0))
    shown = psf_display(stack)
    assert shown.metadata["depths_um"] == pytest.approx([-20.0, 0.0, 20.0], abs=1e-9)
    np.testing.assert_array_equal(shown.data[0], stack.data[1].numpy())


def test_slice_plane_and_depth_readout(viewer):
    viewer.show_psf(spot_stack())
    scene = viewer._scene
    text = scene.model.canvas.overlays.text
    depths = []
    scene.depth_changed.connect(depths.append)
    scene.model.dims.set_current_step(0, 2)
    assert "z = +20.0 µm" in text.text and depths[-1] == pytest.approx(20.0)
    viewer.set_plane("xz")
    assert scene.model.dims.order == (1, 0, 2) and viewer._plane.currentText() == "XZ"
    assert "y = " in text.text and depths[-1] is None
    with pytest.raises(ValueError, match="plane"):
        viewer.set_plane("ab")


def test_orthogonal_projections_follow_the_depth(viewer):
    viewer.show_psf(spot_stack())
    viewer.set_orthogonal(True)
    ortho = viewer._ortho
    assert not ortho.isHidden() and viewer._button_ortho.isChecked()
    xz = ortho._images[0].image
    assert xz.shape == (3, 64)  # (Z, X) max over y
    assert np.argmax(xz[1]) == SPOT[1]  # the spot's column
    viewer._scene.model.dims.set_current_step(0, 0)
    assert ortho._lines[0].isVisible() and ortho._lines[0].value() == pytest.approx(-20.0)
    viewer.set_orthogonal(False)
    assert ortho.isHidden()


def test_fallback_shows_why_and_still_shows_the_data(qtbot):
    view = PSFViewer(use_napari=False)
    qtbot.addWidget(view)
    view.resize(640, 480)
    view.show()
    qtbot.waitExposed(view)
    assert view.backend == "pyqtgraph"
    assert view._message.isVisible() and "requested" in view.message
    view.show_psf(spot_stack())
    view.show_image(torch.rand(32, 32), 6.5e-6)
    view.show_volume(torch.rand(4, 8, 8), (1e-6, 1e-6, 1e-6))
    assert view.layer_names() == ["PSF", "light field", "reconstruction"]
    view.focus("PSF")
    body = view._scene
    assert body.image_view.image.shape == (3, 64, 64)
    assert body.current_depth() == pytest.approx(0.0)  # starts at the middle depth
    body.image_view.setCurrentIndex(0)
    assert body.projections._lines[0].value() == pytest.approx(-20.0)
    qtbot.wait(100)
    shot = _rgb(view.screenshot())
    assert shot.var() > 0 and shot.max() > 100
    view.set_3d(True)  # no 3-D in the fallback: ignored, button disabled
    assert not view.is_3d() and not view._button_3d.isEnabled()
    view.close_viewer()


def test_the_show_combo_is_wide_enough_for_every_layer_name(qtbot):
    """At the default window it read "reconstr" and "light fiel"."""
    view = PSFViewer(use_napari=False)
    qtbot.addWidget(view)
    view.resize(640, 480)
    view.show()
    qtbot.waitExposed(view)
    view.show_image(torch.rand(32, 32), 6.5e-6)
    view.show_volume(torch.rand(4, 8, 8), (1e-6, 1e-6, 1e-6))
    combo = view._combo
    widest = max(combo.fontMetrics().horizontalAdvance(combo.itemText(i)) for i in range(combo.count()))
    # the text and the drop-down arrow, once the toolbar is laid out again (a posted event)
    qtbot.waitUntil(lambda: combo.width() >= widest + 20, timeout=5_000)
    view.close_viewer()


def test_environment_switch_forces_the_fallback(qtbot, monkeypatch):
    monkeypatch.setenv(napari_embed.VIEWER_ENV, "pyqtgraph")
    view = PSFViewer()
    qtbot.addWidget(view)
    assert view.backend == "pyqtgraph" and napari_embed.VIEWER_ENV in view.message
    with pytest.raises(RuntimeError, match="napari cannot run here"):
        PSFViewer(use_napari=True)
    view.close_viewer()


def test_a_canvas_that_fails_to_start_falls_back(qtbot, monkeypatch):
    def broken(**_):
        raise RuntimeError("GLX context lost")

    monkeypatch.setattr(psf_viewer, "NapariScene", broken)
    view = PSFViewer()
    qtbot.addWidget(view)
    assert view.backend == "pyqtgraph" and "GLX context lost" in view.message
    with pytest.raises(RuntimeError, match="GLX"):
        PSFViewer(use_napari=True)
    view.close_viewer()


def _use_and_close_a_viewer(qtbot) -> list[weakref.ref]:
    """Open a viewer with both canvases, close it; return weak references to what must die.

    A helper so that no frame of the test itself (whose locals pytest or Qt may snapshot)
    keeps a reference to the viewer.
    """
    view = PSFViewer(use_napari=True)
    view.show()
    qtbot.waitExposed(view)
    view.show_psf(spot_stack())
    view.set_orthogonal(True)
    view.show_volume(torch.rand(4, 8, 8), (1e-6, 1e-6, 1e-6))  # the second (sample-space) canvas
    canvases = list(view._scene._views.values())
    assert len(canvases) == 2
    refs = [
        weakref.ref(view),
        *(weakref.ref(c) for c in canvases),
        *(weakref.ref(c.viewer) for c in canvases),
    ]
    settle(qtbot, 200)
    view.close_viewer()
    view.close_viewer()  # idempotent
    assert view.layer_names() == [] and view.layer("PSF") is None
    try:
        view.show_psf(spot_stack())
    except RuntimeError as exc:
        assert "closed" in str(exc)
    else:
        raise AssertionError("show_psf after close_viewer must raise")
    view.close()
    view.deleteLater()
    return refs


def test_close_viewer_leaves_no_napari_widgets(qtbot):
    before = set(QApplication.topLevelWidgets())
    refs = _use_and_close_a_viewer(qtbot)
    collect_widgets()
    assert all(ref() is None for ref in refs)
    assert napari_embed.live_qt_viewers() == 0  # napari's make_napari_viewer leak criterion
    leaked = [w for w in QApplication.topLevelWidgets() if w not in before]
    assert not leaked, leaked


def test_calls_from_worker_threads_are_refused(viewer):
    errors = []

    def worker():
        try:
            viewer.show_psf(spot_stack())
        except RuntimeError as exc:
            errors.append(str(exc))

    thread = threading.Thread(target=worker)
    thread.start()
    thread.join()
    assert errors and "GUI thread" in errors[0]
    assert viewer.layer_names() == []


def test_napari_own_fixture_still_works_after_our_viewers(make_napari_viewer):
    # make_napari_viewer fails at set-up if any QtViewer from the tests above is still alive.
    napari_viewer = make_napari_viewer()
    napari_viewer.add_image(np.zeros((4, 4), np.float32))
    assert len(napari_viewer.layers) == 1
