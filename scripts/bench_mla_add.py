"""Time adding one lenslet to a 500-lenslet layout in the studio window (issue 20: up to 0.42 s).

Usage: ``QT_QPA_PLATFORM=offscreen OMP_NUM_THREADS=1 python -W ignore scripts/bench_mla_add.py``.
The default XLFM design with 500 lenslets of 150 um on a 520 um grid inside the pupil (their
2.2 mm sub-images overlap, as in a dense user layout: about 28 overlaps per lenslet); the
window is built as ``lfm-studio gui`` builds it, without the viewer and with a long debounce
(no PSF job). Each add goes through the editor, the design rebuild and every listener.
Prints the median and maximum of 10 adds, in milliseconds: numbers for a report, not a test.
"""

from __future__ import annotations

import statistics
import time

PITCH_UM, HALF_WIDTH_UM, COUNT, ADDS = 520.0, 6600.0, 500, 10


def main() -> None:
    from lfm_studio.engine.design import LensletSpec, MLASpec, load_preset
    from lfm_studio.ui.app import build_studio
    from lfm_studio.ui.widget_factories import prepare_qt_app

    app = prepare_qt_app()
    n = int(HALF_WIDTH_UM // PITCH_UM)
    grid = [(i * PITCH_UM, j * PITCH_UM) for i in range(-n, n + 1) for j in range(-n, n + 1)]
    inside = sorted((p for p in grid if abs(p[0]) < HALF_WIDTH_UM and abs(p[1]) < HALF_WIDTH_UM),
                    key=lambda p: p[0] ** 2 + p[1] ** 2)[:COUNT]  # fmt: skip
    lenslets = tuple(
        LensletSpec(center_um=p, aperture_diameter_um=150.0, focal_length_mm=26.0) for p in inside
    )
    design = load_preset("xlfm_cong2017").updated(mla=MLASpec(lenslets=lenslets))
    window = build_studio(design, debounce_ms=3_600_000, viewer_factory=lambda: None)
    window.show()
    app.processEvents()
    times = []
    for k in range(ADDS):
        start = time.perf_counter()
        window.editor.add_lenslet(
            PITCH_UM / 2.0 + (k - ADDS // 2) * PITCH_UM, PITCH_UM / 2.0
        )  # between lenslets
        app.processEvents()
        times.append(time.perf_counter() - start)
    print(f"{COUNT} lenslets, add one (editor + design + listeners, 1 thread): median "
          f"{statistics.median(times) * 1e3:.0f} ms, max {max(times) * 1e3:.0f} ms over {ADDS} adds")  # fmt: skip
    window.state.replace_design(window.state.design)  # not dirty: close without a prompt
    window.close()


if __name__ == "__main__":
    main()
