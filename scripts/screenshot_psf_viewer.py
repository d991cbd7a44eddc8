"""Screenshot of the PSF viewer on a real small PSF stack (FLFM preset, 512 x 512 sensor, 3 depths).

Usage (headless)::

    xvfb-run -a -s "-screen 0 1600x1000x24" python scripts/screenshot_psf_viewer.py OUT.png [--3d] [--ortho]
        [--fallback]

Writes the whole viewer widget (toolbar, canvas, info line) to ``OUT.png``.
"""

from __future__ import annotations

import argparse

from qt_events import settle  # scripts/, on sys.path when run as a script

from lfm_studio.widgets.viewer.napari_embed import flush_deletions, prepare_qt_app


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="PNG path to write")
    parser.add_argument("--3d", dest="three_d", action="store_true", help="render in 3-D")
    parser.add_argument("--ortho", action="store_true", help="show the XZ/YZ projections")
    parser.add_argument("--layers", action="store_true", help="show napari's layer controls")
    parser.add_argument("--fallback", action="store_true", help="the pyqtgraph fallback")
    args = parser.parse_args()

    app = prepare_qt_app()
    from lfm_studio.engine.design import evolve, load_preset
    from lfm_studio.engine.simulation import simulate_psf
    from lfm_studio.widgets.psf_viewer import PSFViewer

    design = evolve(load_preset("flfm_guo2019"), "camera.pixel_count", (512, 512))
    stack = simulate_psf(design, depths=(-20e-6, 0.0, 20e-6))

    viewer = PSFViewer(use_napari=False if args.fallback else None)
    viewer.resize(1200, 800)
    viewer.show()
    viewer.show_psf(stack)
    if args.ortho:
        viewer.set_orthogonal(True)
    if args.layers and viewer.backend == "napari":
        viewer._button_layers.setChecked(True)
    if args.three_d:
        viewer.set_3d(True)
    settle(app, 2.0)
    viewer.grab().save(args.out)
    print(f"wrote {args.out} ({viewer.backend})")
    viewer.close_viewer()
    viewer.deleteLater()
    flush_deletions()


if __name__ == "__main__":
    main()
