"""A stack replacing another keeps the depth on screen (nearest slice), in napari and in the fallback.

The studio's launch shows a 5-depth preview, then the full stack: on the conventional preset the
full stack landed on z = -80 um (slider 4 of 40) while the preview showed z = 0.
"""

from __future__ import annotations

import numpy as np
import pytest
from qtpy.QtGui import QGuiApplication

from lfm_studio.engine.psf_stack import ConventionalPatterns
from lfm_studio.widgets.psf_viewer import PSFViewer
from lfm_studio.widgets.viewer import napari_embed
from tests.ui.standins import small_conventional_design
from tests.ui.test_psf_viewer import spot_stack

TIMEOUT_MS = 120_000  # generous: only a hang should reach it


def conventional_stack(depths_um):
    """A conventional pattern stack (S, S, Z, H, H) = (3, 3, Z, 65, 65) at ``depths_um``."""
    layout = ConventionalPatterns(
        pixels_per_lenslet=5, voxels_per_lenslet=3, reach=(0,) * len(depths_um), lenslets=(4, 4)
    )
    depths = tuple(float(z) * 1e-6 for z in depths_um)
    return spot_stack(depths, n=65, lead=(3, 3), patterns=layout)


PREVIEW = np.linspace(-100.0, 100.0, 5)  # the preset's preview: 5 of its depths, 50 um apart
FULL = np.linspace(-100.0, 100.0, 41)  # its full stack: 5 um steps


def _napari(qtbot) -> PSFViewer:
    reason = napari_embed.napari_unavailable_reason()
    if reason is not None and QGuiApplication.platformName() in ("offscreen", "minimal"):
        pytest.skip(f"napari canvas needs a display (run under pytest-xvfb): {reason}")
    view = PSFViewer(use_napari=True)
    qtbot.addWidget(view)
    view.resize(640, 480)
    return view


def _napari_depth(view: PSFViewer) -> float:
    """The depth (um) the canvas shows, as its read-out says it."""
    text = view._scene.model.canvas.overlays.text.text
    return float(text.split("z = ")[1].split(" µm")[0])


def _fallback_depth(view: PSFViewer) -> float:
    return view._scene.current_depth()


@pytest.mark.parametrize("backend", ["napari", "fallback"])
def test_the_full_stack_keeps_the_depth_of_the_preview(qtbot, backend):
    if backend == "napari":
        view, depth = _napari(qtbot), _napari_depth
    else:
        view, depth = PSFViewer(use_napari=False), _fallback_depth
        qtbot.addWidget(view)
    view.show_psf(conventional_stack(PREVIEW))
    assert depth(view) == pytest.approx(0.0)
    view.show_psf(conventional_stack(FULL))
    assert depth(view) == pytest.approx(0.0)  # was -80 in napari
    if backend == "napari":
        dims = view._scene.model.dims
        assert dims.current_step[dims.ndim - 3] == 20  # slice 20 of 0..40
        dims.set_current_step(dims.ndim - 3, 30)  # the user looks at +50 um
    else:
        view._scene.image_view.setCurrentIndex(30)
    assert depth(view) == pytest.approx(50.0)
    view.show_psf(conventional_stack((-90.0, -30.0, 30.0, 90.0)))  # no +50 slice: the nearest one
    assert depth(view) == pytest.approx(30.0)
    view.show_psf(conventional_stack(FULL))
    assert depth(view) == pytest.approx(30.0)
    view.close_viewer()


def test_a_shift_invariant_stack_updated_in_place_keeps_the_depth_too(qtbot):
    view = _napari(qtbot)
    view.show_psf(spot_stack(tuple(z * 1e-6 for z in PREVIEW)))
    view.show_psf(spot_stack(tuple(z * 1e-6 for z in FULL)))
    assert _napari_depth(view) == pytest.approx(0.0)
    view.close_viewer()


def test_a_small_conventional_design_shows_its_full_stack_at_the_preview_depth(qtbot):
    """The studio's own path: controller (preview first), viewer binding, real viewer."""
    from lfm_studio.ui.controllers import StudioController, ViewerBinding
    from lfm_studio.ui.state import StudioState

    view = _napari(qtbot)
    state = StudioState(small_conventional_design())  # 17 depths; the preview's 5 are 20 um apart
    controller = StudioController(state, debounce_ms=10, preview=True)
    binding = ViewerBinding(state, view, controller)
    previews: list[float] = []
    state.preview_changed.connect(lambda result: previews.append(_napari_depth(view)))
    controller.start()
    qtbot.waitUntil(lambda: state.psf is not None, timeout=TIMEOUT_MS)
    binding.disconnect_state()
    controller.shutdown()
    assert len(state.psf.stack.depths) == 17 and view.layer("PSF").ndim == 5
    assert previews == [pytest.approx(0.0)]  # the preview came first, at z = 0
    assert _napari_depth(view) == pytest.approx(0.0)  # was -20 (clipped to the preview's span)
    view.close_viewer()
