"""Save docs/screenshots/stale_psf.png: the studio after a PSF job failed on an edited design.

The small Fourier test design (4 lenslets, 256^2 px, 3 depths) is computed once, then its
wavelength is edited and the PSF job made to fail (a stand-in ``compute_psf`` that raises):
the previous PSF stays on screen, marked stale with the error in the viewer's banner, the
PSF profile plots and the requirements table. The failure dialog is closed before the grab.

Headless machines need an X server with OpenGL (napari's canvas)::

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/screenshot_stale.py
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from qt_events import settle, wait_until  # scripts/, on sys.path when run as a script

os.environ.setdefault("QT_API", "pyside6")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))  # tests.ui.standins: the small design
ERROR = "not enough memory for the PSF stack (a stand-in failure for this screenshot)"


def _fail(ctx, request, cache):
    raise RuntimeError(ERROR)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "screenshots" / "stale_psf.png")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds to wait for each stage")
    args = parser.parse_args(argv)

    from qtpy.QtCore import QSettings
    from qtpy.QtWidgets import QApplication

    from lfm_studio.ui import pipeline
    from lfm_studio.ui.app import build_studio
    from lfm_studio.ui.edits import apply_changes
    from lfm_studio.widgets.viewer.napari_embed import prepare_qt_app
    from tests.ui.standins import small_fourier_design

    app = prepare_qt_app()
    design = small_fourier_design()
    settings = QSettings(str(Path(tempfile.mkdtemp()) / "settings.ini"), QSettings.Format.IniFormat)
    window = build_studio(design, settings=settings, preview=False, debounce_ms=10)
    window.resize(1600, 1000)
    window.show()
    state, controller = window.state, window.controller
    controller.start()
    wait_until(app, lambda: state.psf is not None and "psf" not in state.stale, args.timeout, "the PSF")
    wait_until(app, lambda: not state.busy, args.timeout, "the metrics")
    pipeline.compute_psf = _fail
    state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))
    controller.flush()
    wait_until(app, lambda: state.job("psf").state == "failed", args.timeout, "the failure")
    settle(app, 1.0)
    if window.failure_notices.last is not None:
        window.failure_notices.last.close()
    settle(app, 2.0)  # let napari and the plots draw
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if not window.grab().save(str(args.out)):
        raise SystemExit(f"screenshot_stale: could not write {args.out}")
    print(f"wrote {args.out}; viewer banner: {window.viewer.stale_text!r}")
    state.set_dirty(False)
    window.close()
    settle(app, 0.5)
    QApplication.processEvents()
    return 0


if __name__ == "__main__":
    sys.exit(main())
