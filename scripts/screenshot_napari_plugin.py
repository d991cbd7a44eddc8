"""Screenshot of the napari plugin: bead sample data, the Reconstruct widget after a run, result vs truth.

Opens napari, loads *File > Open Sample > lfm-studio > Bead light field*, docks
*Reconstruct light field*, reconstructs the sample (accelerated Richardson-Lucy) and saves
the whole window, showing the reconstruction's maximum projection over depth with the
ground-truth beads (cyan) on top. Headless machines need an X server with OpenGL (napari's canvas)::

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/screenshot_napari_plugin.py \
        [--out docs/screenshots/napari_plugin.png] [--2d]

``--2d`` shows the light-field image instead of the 3-D reconstruction.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from qt_events import settle, wait_until  # scripts/, on sys.path when run as a script

os.environ.setdefault("QT_API", "pyside6")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

REPO = Path(__file__).resolve().parents[1]
WINDOW_SIZE = (1600, 1000)
PLUGIN = "lfm-studio"


def _frame(viewer, layer, fill: float = 0.8) -> None:
    """Centre the camera on ``layer`` and zoom so it fills ``fill`` of the canvas (reset_view fits all layers,
    hidden ones included, and the camera image is about 30 times wider than the volume)."""
    import numpy as np

    lower, upper = np.asarray(layer.extent.world)
    native = viewer.window._qt_viewer.canvas.native
    shown = viewer.dims.ndisplay
    camera = viewer.scene.camera
    camera.center = tuple((lower + upper)[-shown:] / 2.0)
    height, width = (upper - lower)[-2:]
    camera.zoom = fill * min(native.width() / width, native.height() / height)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(REPO / "docs" / "screenshots" / "napari_plugin.png"))
    parser.add_argument("--2d", dest="two_d", action="store_true", help="show the light-field image")
    parser.add_argument("--iterations", type=int, default=20)
    args = parser.parse_args()

    from lfm_studio.widgets.viewer.napari_embed import prepare_qt_app

    app = prepare_qt_app()
    import napari

    viewer = napari.Viewer(title="napari + lfm-studio", show=True)
    window = viewer.window._qt_window
    window.resize(*WINDOW_SIZE)
    viewer.open_sample(PLUGIN, "beads")
    dock, widget = viewer.window.add_plugin_dock_widget(PLUGIN, "Reconstruct light field")
    from qtpy.QtCore import Qt

    window.resizeDocks([dock], [380], Qt.Orientation.Horizontal)
    widget.set_method("rl-accelerated")
    widget.iterations.setValue(args.iterations)
    if not widget.start():
        raise SystemExit("screenshot: the reconstruction was refused (see the notification)")
    wait_until(app, lambda: not widget.busy, 600, "the reconstruction")
    result, truth = viewer.layers[-1], viewer.layers["beads ground truth"]
    for layer in viewer.layers:
        layer.visible = layer in (result, truth) if not args.two_d else layer.name == "beads light field"
    viewer.canvas.overlays.scale_bar.visible = True
    if args.two_d:
        viewer.layers.selection.active = viewer.layers["beads light field"]
    else:
        # a maximum-intensity projection over every depth: all beads at once, the truth (cyan) on top
        depth_range = result.extent.world[1][0] - result.extent.world[0][0]
        slab = depth_range + 2.0 * result.scale[0]  # napari's slab ends are half-open: one step spare
        viewer.dims.thickness = (slab, *viewer.dims.thickness[1:])
        result.projection_mode = "max"
        truth.projection_mode = "max"
        truth.colormap, truth.blending, truth.opacity = "cyan", "additive", 0.6
        truth.contrast_limits = (0.0, 1.0)
        result.blending, result.gamma = "additive", 0.7
        viewer.layers.move(viewer.layers.index(truth), len(viewer.layers))  # the truth on top
        viewer.layers.selection.active = result
    _frame(viewer, viewer.layers.selection.active)
    settle(app, 3.0)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    window.grab().save(args.out)
    print(f"wrote {args.out}")
    viewer.close()


if __name__ == "__main__":
    main()
