"""Regenerate the README screenshots in docs/screenshots/ (and, with ``--workflow``, every display state).

Starts the studio exactly as ``lfm-studio gui`` does (:func:`lfm_studio.ui.app.launch_studio`:
the bundled default design, XLFM after Cong et al. 2017, the real napari viewer, preview on),
waits until the quick PSF preview has been computed and drawn, and saves:

- ``main_window.png``: the whole window (parameters, MLA editor, viewer, plots, status bar);
- ``mla_editor.png``: the MLA layout editor dock;
- ``viewer.png``: the PSF viewer.

``--full`` waits for the full PSF stack and its measured metrics first (minutes on a CPU).
``--workflow DIR`` (implies ``--full``) then presses "Simulate image" and "Reconstruct" and
saves the viewer in each state to DIR: ``psf_full.png``, ``light_field.png``, ``phantom.png``,
``phantom_mip.png``, ``reconstruction.png`` (its brightest slice) and ``reconstruction_mip.png``,
plus ``main_window_workflow.png`` (the status bar's stage trail with times).
``--raw-demo DIR`` starts from the nominal design of a synthetic misaligned instrument
(:func:`lfm_studio.engine.calibration.synthetic_scene.misaligned_bead_scene`, its frames written
to DIR), fills File > Open raw light field… (``raw_dialog.png``), calibrates, accepts the
calibration's design and reconstructs: ``raw_light_field.png``, ``raw_reconstruction.png``,
``main_window_raw.png``.
``--video-dialog`` also saves File > Reconstruct light-field video… filled in (``video_dialog.png``,
example paths; nothing runs).

Headless machines need an X server with OpenGL (napari's canvas)::

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/screenshots.py
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from qt_events import settle, wait_until  # scripts/, on sys.path when run as a script

os.environ.setdefault("QT_API", "pyside6")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

REPO = Path(__file__).resolve().parents[1]
WINDOW_SIZE = (1600, 1000)


def _save(widget, target: Path) -> None:
    if not widget.grab().save(str(target)):
        raise SystemExit(f"screenshots: could not write {target}")
    print(f"wrote {target} ({widget.width()} x {widget.height()})")


def _finished(state, job: str):
    return lambda: state.job(job).state in ("done", "failed", "cancelled")


def _require_done(state, job: str) -> None:
    status = state.job(job)
    if status.state != "done":
        raise SystemExit(f"screenshots: the {job} stage ended {status.state}: {status.message}")


def _workflow_states(app, window, out: Path, timeout: float) -> None:
    """Simulate, reconstruct, and save the viewer at each display state."""
    state, viewer, panel = window.state, window.viewer, window.workflow_panel
    out.mkdir(parents=True, exist_ok=True)
    _save(viewer, out / "psf_full.png")
    panel.simulate_button.click()
    wait_until(app, _finished(state, "image"), timeout, "the image")
    _require_done(state, "image")
    settle(app, 2.0)
    _save(viewer, out / "light_field.png")
    panel.reconstruct_button.click()
    wait_until(app, _finished(state, "reconstruction"), timeout, "the reconstruction")
    _require_done(state, "reconstruction")
    settle(app, 2.0)
    _save(viewer, out / "reconstruction.png")
    viewer.set_mip(True)
    settle(app, 2.0)
    _save(viewer, out / "reconstruction_mip.png")
    viewer.focus("phantom")
    settle(app, 2.0)
    _save(viewer, out / "phantom_mip.png")
    viewer.set_mip(False)
    settle(app, 2.0)
    _save(viewer, out / "phantom.png")
    viewer.focus("reconstruction")
    settle(app, 1.0)
    _save(window, out / "main_window_workflow.png")


def _raw_demo_files(out: Path) -> dict[str, str]:
    """The synthetic misaligned scene's nominal design and frames, written to ``out``."""
    import numpy as np
    import tifffile

    from lfm_studio.engine.calibration.synthetic_scene import misaligned_bead_scene
    from lfm_studio.engine.design import save_design

    out.mkdir(parents=True, exist_ok=True)
    scene = misaligned_bead_scene()
    files = {"design": str(save_design(scene.nominal, out / "nominal.json", overwrite=True))}
    for name in ("raw", "radiometry", "dark"):
        frame = getattr(scene, name).clamp(0, 65535).round().numpy().astype(np.uint16)
        tifffile.imwrite(out / f"{name}.tif", frame)
        files[name] = str(out / f"{name}.tif")
    return files


def _raw_demo(app, window, files: dict[str, str], out: Path, timeout: float) -> None:
    """Open the raw frame with a calibration made from the radiometry and dark frames, reconstruct."""
    from lfm_studio.ui.raw_frame_dialog import JOB, RawFrameDialog

    state, viewer, raw_frames = window.state, window.viewer, window.file_actions.raw_frames
    dialog = RawFrameDialog(window)
    dialog.make_new.setChecked(True)
    dialog.raw_edit.setText(files["raw"])
    dialog.radiometry_edit.setText(files["radiometry"])
    dialog.dark_edit.setText(files["dark"])
    dialog.show()
    settle(app, 0.5)
    _save(dialog, out / "raw_dialog.png")
    request = dialog.request(state.design)
    dialog.close()
    raw_frames.load(request, use_fitted=True)
    wait_until(app, lambda: state.image is not None or (_finished(state, JOB)() and state.job(JOB).state != "done"),
               timeout, "the raw frame")  # fmt: skip
    _require_done(state, JOB)
    settle(app, 2.0)
    _save(viewer, out / "raw_light_field.png")
    window.workflow_panel.reconstruct_button.click()
    wait_until(app, _finished(state, "reconstruction"), timeout, "the reconstruction")
    _require_done(state, "reconstruction")
    viewer.set_mip(True)
    settle(app, 2.0)
    _save(viewer, out / "raw_reconstruction.png")
    _save(window, out / "main_window_raw.png")


def _video_dialog(app, window, out: Path) -> None:
    """File > Reconstruct light-field video… as it opens for the current design, with example paths."""
    from lfm_studio.ui.video_dialog import VideoDialog, method_text

    state = window.state
    dialog = VideoDialog(window, method_text=method_text(state.workflow, state.design))
    dialog.frames_edit.setText("/data/zebrafish/recording_30hz.tif")
    dialog.output_edit.setText("/data/zebrafish/recording_30hz.ome.zarr")
    dialog.show()
    settle(app, 0.5)
    _save(dialog, out / "video_dialog.png")
    dialog.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "screenshots")
    parser.add_argument("--design", default=None, help="preset name or design file (default: the studio's)")
    parser.add_argument("--full", action="store_true", help="wait for the full PSF stack too")
    parser.add_argument("--workflow", type=Path, default=None, help="also save every display state here")
    parser.add_argument("--timeout", type=float, default=1200.0, help="seconds to wait for each stage")
    parser.add_argument("--raw-demo", type=Path, default=None, help="open a synthetic raw frame; shots here")
    parser.add_argument(
        "--video-dialog", action="store_true", help="also save the video dialog (video_dialog.png)"
    )
    args = parser.parse_args(argv)
    raw_files = None if args.raw_demo is None else _raw_demo_files(args.raw_demo)
    if raw_files is not None:
        args.design = raw_files["design"]

    from qtpy.QtWidgets import QApplication

    from lfm_studio.ui.app import launch_studio

    window = launch_studio(args.design)  # exactly what `lfm-studio gui` does before app.exec()
    app = QApplication.instance()
    window.resize(*WINDOW_SIZE)
    state = window.state
    if args.full or args.workflow is not None:
        wait_until(
            app, lambda: state.psf is not None and _finished(state, "metrics")(), args.timeout, "the PSF"
        )
        _require_done(state, "psf")
    else:
        wait_until(
            app, lambda: state.preview is not None or state.psf is not None, args.timeout, "the preview"
        )
    settle(app, 2.0)  # let napari and the plots draw

    args.out.mkdir(parents=True, exist_ok=True)
    shots = {
        "main_window.png": window,
        "mla_editor.png": window.editor if window.editor is not None else None,
        "viewer.png": window.viewer,
    }
    for name, widget in shots.items():
        if widget is None:
            print(f"skipped {name}: widget not available", file=sys.stderr)
            continue
        _save(widget, args.out / name)
    if args.workflow is not None:
        _workflow_states(app, window, args.workflow, args.timeout)
    if raw_files is not None:
        _raw_demo(app, window, raw_files, args.raw_demo, args.timeout)
    if args.video_dialog:
        _video_dialog(app, window, args.out)

    window.controller.cancel()
    state.set_dirty(False)
    window.close()
    settle(app, 0.5)
    return 0


if __name__ == "__main__":
    sys.exit(main())
