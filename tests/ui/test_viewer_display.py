"""What the viewer shows: layer replacement without errors, visible sparse PSFs, MIP, brightest slice."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch
from qtpy.QtGui import QGuiApplication

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.psf_stack import ConventionalPatterns, PSFStack
from lfm_studio.widgets.psf_viewer import PSFViewer
from lfm_studio.widgets.viewer import napari_embed
from lfm_studio.widgets.viewer.display_data import (
    brightest_slice,
    describe,
    image_display,
    psf_display,
    rectified_note,
    volume_display,
)
from lfm_studio.widgets.viewer.napari_scene import position_text
from tests.ui.test_psf_viewer import _rgb, hide_overlays, settle, spot_stack


def _napari_view(qtbot, **kwargs) -> PSFViewer:
    reason = napari_embed.napari_unavailable_reason()
    if reason is not None and QGuiApplication.platformName() in ("offscreen", "minimal"):
        pytest.skip(f"napari canvas needs a display (run under pytest-xvfb): {reason}")
    view = PSFViewer(use_napari=True, **kwargs)
    qtbot.addWidget(view)
    view.resize(640, 480)
    return view


@pytest.fixture
def hook_errors(monkeypatch):
    errors: list[BaseException] = []
    monkeypatch.setattr(sys, "excepthook", lambda t, value, tb: errors.append(value))
    return errors


def test_a_preview_replaced_by_a_stack_of_another_pyramid_depth_raises_nothing(qtbot, hook_errors):
    # The studio's launch: a 3-depth preview, then the full stack whose pyramid has one level more.
    # napari emits dims events from inside layers.remove(); they used to reach _on_step with the
    # focused name already forgotten (KeyError: 'PSF').
    view = _napari_view(qtbot, max_voxels_3d=3 * 16 * 16)
    view.show_psf(spot_stack())
    preview = view.layer("PSF")
    assert len(preview.data) == 3
    full = spot_stack(depths=(-40e-6, -20e-6, 0.0, 20e-6, 40e-6))
    view.show_psf(full)  # raised KeyError before the fix
    layer = view.layer("PSF")
    assert layer is not preview and len(layer.data) == 4 and layer.data[0].shape == (5, 64, 64)
    assert view.layer_names() == ["PSF"] and view._scene.focused == "PSF" and layer.visible
    assert [lay.name for lay in view._scene.model.layers] == ["PSF"]  # the old layer is gone from napari
    assert "z = " in view._scene.model.canvas.overlays.text.text  # read-out of the new layer
    assert hook_errors == []
    view.close_viewer()


def test_replacing_a_layer_that_is_not_on_screen_keeps_the_focus(qtbot, hook_errors):
    view = _napari_view(qtbot, max_voxels_3d=3 * 16 * 16)
    view.show_psf(spot_stack())
    view.show_image(torch.rand(32, 32), 6.5e-6)
    assert view._scene.focused == "light field"
    view.show_psf(spot_stack(depths=(-40e-6, -20e-6, 0.0, 20e-6, 40e-6)))  # replaced, not focused
    assert view._scene.focused == "light field" and not view.layer("PSF").visible
    view.focus("PSF")
    assert view.layer("PSF").visible and not view.layer("light field").visible
    assert hook_errors == []
    view.close_viewer()


def sparse_psf(n: int = 1024) -> PSFStack:
    """A Fourier-LFM-like PSF: 25 sharp spots (core sigma 0.8 px, a faint 2 % halo) in an n x n frame."""
    yy, xx = torch.meshgrid(
        torch.arange(n, dtype=torch.float32), torch.arange(n, dtype=torch.float32), indexing="ij"
    )
    image = torch.zeros(n, n)
    for cy in np.linspace(n * 0.2, n * 0.8, 5):
        for cx in np.linspace(n * 0.2, n * 0.8, 5):
            r2 = (yy - float(cy)) ** 2 + (xx - float(cx)) ** 2
            image += torch.exp(-r2 / (2 * 0.8**2)) + 0.02 * torch.exp(-r2 / (2 * 6.0**2))
    return PSFStack(image.expand(3, n, n).contiguous(), (-10e-6, 0.0, 10e-6), 6.5e-6, 20.0, 500e-9)


def _lit(view: PSFViewer, qtbot, threshold: int = 60) -> int:
    settle(qtbot, 600)
    return int((_rgb(view.screenshot()).max(axis=-1) > threshold).sum())


def test_a_sparse_psf_is_drawn_visibly_larger_than_with_a_linear_min_max_display(qtbot):
    stack = sparse_psf()
    shown = psf_display(stack)
    data = stack.data.numpy()
    # 0.1-99.9 % limits (independent numpy reference) and gamma 0.5.
    low, high = np.percentile(data, [0.1, 99.9])
    assert shown.contrast_limits == pytest.approx((low, high), rel=0.02, abs=1e-7)  # sampled percentiles
    assert shown.gamma == pytest.approx(0.5) and high < 0.1 * data.max()

    view = _napari_view(qtbot)
    view.show()
    qtbot.waitExposed(view)
    view.show_display(shown)
    hide_overlays(view)
    ours = _lit(view, qtbot)
    linear = psf_display(stack)
    linear.contrast_limits, linear.gamma = linear.data_range, 1.0  # the floor: plain min-max
    view.show_display(linear)
    floor = _lit(view, qtbot)
    # 25 spots: the linear display lights only their single central pixels (on the pooled level).
    assert ours >= 4 * max(floor, 1), (ours, floor)
    view.close_viewer()


def beads_volume() -> torch.Tensor:
    """Two 5 x 5 beads at depths 1 and 4 (of 6): any single slice shows at most one."""
    volume = torch.zeros(6, 48, 48)
    volume[1, 8:13, 8:13] = 1.0
    volume[4, 34:39, 34:39] = 3.0  # the brightest slice is 4
    return volume


def test_a_slice_position_that_rounds_to_zero_reads_plus_zero():
    """The full XLFM stack's middle depth (-1e-15 um after the depth arithmetic) read "z = -0.0 µm"."""
    assert [position_text(v) for v in (-1e-15, -0.04, 0.0, 2.5, -80.0)] == [
        "+0.0 µm", "+0.0 µm", "+0.0 µm", "+2.5 µm", "-80.0 µm",
    ]  # fmt: skip


def test_brightest_slice_of_a_volume():
    volume = beads_volume().numpy()
    assert brightest_slice(volume) == 4
    assert brightest_slice(np.zeros((3, 4, 4), np.float32)) == 0
    assert volume_display(beads_volume(), (2e-6, 1e-6, 1e-6)).initial_step == {0: 4}


def test_a_volume_opens_at_its_brightest_slice_and_mip_shows_every_bead(qtbot, hook_errors):
    view = _napari_view(qtbot)
    view.show()
    qtbot.waitExposed(view)
    view.show_psf(spot_stack())
    assert not view.is_mip()  # a PSF opens on one depth
    view.show_volume(beads_volume(), (2e-6, 1e-6, 1e-6), name="phantom")
    # A sample volume opens as its MIP (one slice of a bead volume holds few beads: it read as empty).
    assert view.is_mip() and view._button_mip.isChecked() and view.layer("phantom").projection_mode == "max"
    view.set_mip(False)
    hide_overlays(view)
    dims = view._scene.model.dims
    assert dims.current_step[0] == 4  # the slice view is at the brightest slice, not z = 0
    dims.set_current_step(0, 2)  # an empty slice: nothing drawn
    assert _lit(view, qtbot) == 0
    view._button_mip.click()  # the toolbar toggle
    assert view.is_mip() and view.layer("phantom").projection_mode == "max"
    assert "MIP" in view._scene.model.canvas.overlays.text.text
    hide_overlays(view)
    both = _lit(view, qtbot)
    view.set_mip(False)
    dims.set_current_step(0, 4)
    one = _lit(view, qtbot)
    # MIP draws both beads (equal areas), the brightest slice one of them.
    assert one > 0 and both == pytest.approx(2 * one, rel=0.25), (both, one)
    assert not view._button_mip.isChecked() and view.layer("phantom").projection_mode == "none"
    view.focus("PSF")  # each space keeps its own choice
    assert not view.is_mip() and view.layer("PSF").projection_mode == "none"
    assert hook_errors == []
    view.close_viewer()


def test_a_bead_reconstruction_is_drawn_against_its_bright_voxels_not_its_single_brightest():
    """RL beads: a bright peak voxel over a blur and a faint positive floor. With the maximum as the
    upper limit (linear), only each bead's peak voxel lit: about a screen pixel, and the view read empty."""
    rng = np.random.default_rng(1)
    volume = rng.uniform(0.5, 5.0, (8, 200, 200)).astype(np.float32)  # the floor RL leaves everywhere
    peaks = rng.uniform(3e5, 9e5, 20)
    for k, (z, y, x) in enumerate(
        zip(rng.integers(1, 7, 20), rng.integers(5, 195, 20), rng.integers(5, 195, 20), strict=True)
    ):
        volume[z, y - 2 : y + 3, x - 2 : x + 3] = peaks[k] * 1e-3  # the blur around the peak
        volume[z, y, x] = peaks[k]
    shown = volume_display(torch.from_numpy(volume), (5e-6, 2.5e-6, 2.5e-6))
    low, high = shown.contrast_limits
    nonzero = volume[volume != 0]
    assert high == pytest.approx(np.percentile(nonzero, 99.99), rel=0.02)  # independent numpy reference
    assert low == pytest.approx(volume.min()) and high < 0.01 * volume.max()
    blur_level = ((peaks.min() * 1e-3 - low) / (high - low)) ** shown.gamma
    assert blur_level > 0.3  # a bead's blur is drawn visibly, not only its peak voxel


def _pattern_stack(design) -> PSFStack:
    """A one-depth conventional pattern stack of ``design`` (19 pixels per 125 um lenslet: 6.579 um)."""
    q = 19
    return PSFStack(
        data=torch.ones(1, 1, 1, 3 * q, 3 * q),
        depths=(0.0,),
        pixel_size=125e-6 / q,
        magnification=10.0,
        wavelength=525e-9,
        design=design,
        patterns=ConventionalPatterns(
            pixels_per_lenslet=q, voxels_per_lenslet=1, reach=(0,), lenslets=(8, 8)
        ),
    )


def test_a_conventional_stack_and_its_light_field_say_the_sensor_was_resampled():
    """The 10x design's camera has 6.5 um pixels; its PSF and image use 6.579 um (19 per lenslet): the
    info lines say so, and a stack whose pixels are the camera's says nothing."""
    design = load_preset("lfm_10x_na03")
    stack = _pattern_stack(design)
    note = "resampled from the camera's 6.5 µm pixels to 19 whole pixels per lenslet"
    assert note in describe(psf_display(stack))
    light_field = image_display(torch.ones(8, 8), stack.pixel_size, note=rectified_note(stack))
    assert describe(light_field) == f"light field: 8×8 camera pixels of 6.57895 µm ({note})"
    as_camera = design.updated(camera={**design.camera.model_dump(), "pixel_pitch_um": 125 / 19})
    assert "resampled" not in describe(psf_display(_pattern_stack(as_camera)))
    assert rectified_note(_pattern_stack(as_camera)) is None
