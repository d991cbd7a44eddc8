"""Regenerate the README screenshots in docs/screenshots/.

Opens the studio on the bundled default design (XLFM after Cong et al. 2017), waits
until the quick PSF preview has been computed and drawn, and saves:

- ``main_window.png``: the whole window (parameters, MLA editor, viewer, plots, status bar);
- ``mla_editor.png``: the MLA layout editor dock;
- ``viewer.png``: the PSF viewer.

Headless machines need an X server with OpenGL (napari's canvas)::

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/screenshots.py

Options: ``--out DIR`` (default docs/screenshots), ``--design NAME_OR_FILE``,
``--full`` (also wait for the full PSF stack and its measured metrics; minutes on a CPU).
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "screenshots")
    parser.add_argument("--design", default=None, help="preset name or design file (default: the studio's)")
    parser.add_argument("--full", action="store_true", help="wait for the full PSF stack too")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds to wait for each stage")
    args = parser.parse_args(argv)

    from lfm_studio.ui.app import _open, build_studio
    from lfm_studio.ui.widget_factories import prepare_qt_app, warm_up_viewer

    design, path = _open(args.design)
    app = prepare_qt_app()
    window = build_studio(design, file_path=path)
    warm_up_viewer(window.viewer)  # as run_studio does
    window.resize(*WINDOW_SIZE)
    window.show()
    state = window.state
    window.controller.start()
    if args.full:
        wait_until(
            app,
            lambda: state.psf is not None and state.job("metrics").state == "done",
            args.timeout,
            "the PSF",
        )
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
        target = args.out / name
        if not widget.grab().save(str(target)):
            raise SystemExit(f"screenshots: could not write {target}")
        print(f"wrote {target} ({widget.width()} x {widget.height()})")

    window.controller.cancel()
    state.set_dirty(False)
    window.close()
    settle(app, 0.5)
    return 0


if __name__ == "__main__":
    sys.exit(main())
