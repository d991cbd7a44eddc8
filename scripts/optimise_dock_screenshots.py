"""Screenshots of the studio's Optimise dock, one per method, after a small run of each.

Builds the studio on the small test design (``tests/ui/standins.small_fourier_design``: 4
lenslets, a 256² sensor, 3 depths; no PSF work in the background), floats the Optimise dock
at 1300 x 520 px and saves into OUT (default docs/screenshots):

- ``optimise_dock.png``: grid search, the relay focal length at 80-110 mm, lateral resolution;
- ``optimise_dock_algorithm2.png``: Algorithm 2 on the FLFM preset, 800 µm cells, lateral resolution;
- ``optimise_dock_gradient.png``: gradient PSF engineering of the axial CRB, 8 Adam steps from an
  out-of-focus start (22 mm lenslets, camera 15 mm behind them);
- ``optimise_dock_end_to_end.png``: 4 end-to-end steps (batch 1, 2 held-out phantoms).

Headless::

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/optimise_dock_screenshots.py [OUT]
"""

from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path

from qt_events import settle, wait_until  # scripts/, on sys.path when run as a script

os.environ.setdefault("QT_API", "pyside6")
os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")

REPO = Path(__file__).resolve().parents[1]
DOCK_SIZE = (1300, 520)
FOCUS = {"mla.lenslets[*].focal_length_mm": (12.0, 24.0), "mla_to_camera_distance_mm": (14.0, 20.0)}
OUT_OF_FOCUS = {"mla.lenslets[*].focal_length_mm": 22.0, "mla_to_camera_distance_mm": 15.0}


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    out = Path(args[0]) if args else REPO / "docs" / "screenshots"
    out.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(REPO))
    from qtpy.QtCore import QSettings, Qt
    from qtpy.QtWidgets import QDockWidget

    from lfm_studio.engine.design import load_preset
    from lfm_studio.engine.design.errors import DesignWarning
    from lfm_studio.engine.optimize import DesignSpace, Parameter
    from lfm_studio.ui.app import build_studio
    from lfm_studio.ui.optimise_dock import JOB_NAME
    from lfm_studio.widgets.viewer.napari_embed import prepare_qt_app
    from tests.ui.standins import FakeMLAEditor, FakePSFViewer, small_fourier_design

    warnings.simplefilter("ignore", DesignWarning)
    app = prepare_qt_app()
    settings = QSettings(str(out / ".optimise_dock_screenshots.ini"), QSettings.Format.IniFormat)
    window = build_studio(
        small_fourier_design(), settings=settings, debounce_ms=600_000,
        editor_factory=lambda d: FakeMLAEditor(d.mla.lenslets), viewer_factory=FakePSFViewer,
    )  # fmt: skip
    window.resize(1600, 1000)
    window.show()
    dock = window.optimise
    holder = next(d for d in window.findChildren(QDockWidget) if d.widget() is dock)
    holder.setFloating(True)
    holder.resize(*DOCK_SIZE)
    holder.show()

    def run_and_save(name: str) -> None:
        dock.run_button.click()
        wait_until(app, lambda: window.state.job(JOB_NAME).state != "running", 600, f"the {name} run")
        if window.state.job(JOB_NAME).state != "done":
            raise SystemExit(f"screenshots: the {name} run ended {window.state.job(JOB_NAME).state}")
        settle(app, 0.5)
        target = out / name
        if not dock.grab().save(str(target)):
            raise SystemExit(f"screenshots: could not write {target}")
        print(f"wrote {target}: {dock.message.text()}")

    dock.free("relay.focal_length_mm", 80.0, 110.0, 4)
    dock.set_objectives(["lateral_resolution"])
    dock.budget.setValue(4)
    run_and_save("optimise_dock.png")
    dock.parameters.item(dock.parameter_row("relay.focal_length_mm"), 0).setCheckState(
        Qt.CheckState.Unchecked
    )

    window.state.set_design(load_preset("flfm_guo2019"))
    dock.set_method("algorithm2")
    dock.a2_objective.setCurrentText("lateral_resolution")
    dock.a2_min_lenslet.setText("800")
    run_and_save("optimise_dock_algorithm2.png")

    space = DesignSpace(tuple(Parameter(path, *bounds) for path, bounds in FOCUS.items()))
    window.state.set_design(space.apply(small_fourier_design(), OUT_OF_FOCUS))
    dock.set_method("gradient-psf")
    for path, (low, high) in FOCUS.items():
        dock.free(path, low, high, 3)
    dock.g_steps.setText("8")
    dock.g_lr.setText("0.1")
    run_and_save("optimise_dock_gradient.png")

    dock.set_method("gradient-end-to-end")
    dock.g_steps.setText("4")
    dock.e_batch.setText("1")
    dock.e_held_out.setText("2")
    run_and_save("optimise_dock_end_to_end.png")

    window.state.set_dirty(False)
    window.close()
    (out / ".optimise_dock_screenshots.ini").unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
