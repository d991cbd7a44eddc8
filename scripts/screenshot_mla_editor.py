"""Screenshot of the MLA layout editor on the bundled XLFM-like design (for the README and reviews).

Usage (needs a display; headless: ``xvfb-run -a -s "-screen 0 1600x1000x24"``)::

    python scripts/screenshot_mla_editor.py OUTPUT.png [--preset xlfm_cong2017] [--select 0 5] [--size 1400 900]
"""

from __future__ import annotations

import argparse
import os
import sys


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("output", help="PNG file to write")
    parser.add_argument("--preset", default="xlfm_cong2017", help="bundled design whose MLA is shown")
    parser.add_argument("--select", type=int, nargs="*", default=[0], help="lenslet indices to select")
    parser.add_argument("--size", type=int, nargs=2, default=(1400, 900), metavar=("W", "H"))
    args = parser.parse_args(argv)

    os.environ.setdefault("QT_API", "pyside6")
    os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")
    from qtpy.QtWidgets import QApplication

    from lfm_studio.engine.design import load_preset
    from lfm_studio.widgets.mla_editor import MLAEditor

    app = QApplication.instance() or QApplication(sys.argv[:1])
    design = load_preset(args.preset)
    pupil = design.pupil_diameter_at_mla
    sub_image = design.sub_image_radius
    editor = MLAEditor(
        design.mla.lenslets,
        pupil_radius_um=None if pupil is None else pupil / 2.0 / 1e-6,
        sensor_size_um=tuple(s / 1e-6 for s in design.camera.sensor_size),
    )
    editor.set_sensor(
        tuple(s / 1e-6 for s in design.camera.sensor_size),
        None if sub_image is None else sub_image / 1e-6,
        pixel_pitch_um=design.camera.pixel_pitch_um,
    )
    editor.setWindowTitle(f"MLA layout editor - {design.name}")
    editor.resize(*args.size)
    editor.show()
    editor.set_selection(args.select)
    for _ in range(20):
        app.processEvents()
    editor.fit()
    app.processEvents()
    ok = editor.grab().save(args.output)
    editor.close()
    editor.deleteLater()
    app.processEvents()
    print(f"wrote {args.output}" if ok else f"could not write {args.output}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
