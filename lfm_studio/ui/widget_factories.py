"""The one place where the studio imports the reusable widgets and the napari app setup.

:mod:`lfm_studio.widgets` (MLA editor, PSF viewer, napari embedding) is imported lazily
here only, so the window can be assembled with stand-ins (tests) and a missing or
broken widget module shows a message instead of stopping the studio.
"""

from __future__ import annotations

import importlib
import os
from collections.abc import Callable
from typing import Any

from qtpy.QtCore import Qt
from qtpy.QtWidgets import QApplication, QLabel, QWidget

from lfm_studio.engine.design import Design

EditorFactory = Callable[[Design], QWidget | None]
ViewerFactory = Callable[[], QWidget | None]


def _optional(module: str) -> Any | None:
    try:
        return importlib.import_module(module)
    except ImportError:
        return None


def prepare_qt_app() -> QApplication:
    """The QApplication (napari's, with shared OpenGL contexts, when napari is available)."""
    os.environ.setdefault("QT_API", "pyside6")
    os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")
    embed = _optional("lfm_studio.widgets.viewer.napari_embed")
    if embed is not None and hasattr(embed, "prepare_qt_app"):
        return embed.prepare_qt_app()
    app = QApplication.instance()
    if app is None:
        QApplication.setAttribute(Qt.ApplicationAttribute.AA_ShareOpenGLContexts)
        app = QApplication([])
    return app


def make_mla_editor(design: Design) -> QWidget | None:
    """The MLA layout editor on ``design``'s lenslets, or None when the editor is unavailable."""
    from lfm_studio.ui.controllers import editor_lenslets, editor_pupil_radius_um

    module = _optional("lfm_studio.widgets.mla_editor")
    if module is None:
        return None
    width, height = design.camera.sensor_size
    return module.MLAEditor(
        editor_lenslets(design),
        pupil_radius_um=editor_pupil_radius_um(design),
        sensor_size_um=(width * 1e6, height * 1e6),
    )


def make_psf_viewer() -> QWidget | None:
    """The PSF / image / reconstruction viewer (napari, or its pyqtgraph fallback); None when unavailable."""
    module = _optional("lfm_studio.widgets.psf_viewer")
    return None if module is None else module.PSFViewer()


def warm_up_viewer(viewer: QWidget | None) -> None:
    """Pay the viewer's first-layer cost now, at startup (napari's lazy imports and layer set-up:
    about 1 s here), instead of freezing the window when the first PSF arrives."""
    if viewer is None or not hasattr(viewer, "show_psf"):
        return
    import torch

    from lfm_studio.engine.psf_stack import PSFStack

    tiny = PSFStack(
        torch.zeros(2, 8, 8), (0.0, 1e-6), pixel_size=6.5e-6, magnification=1.0, wavelength=500e-9
    )
    viewer.show_psf(tiny)
    viewer.clear()


def unavailable(what: str) -> QWidget:
    """A message in place of a widget this installation lacks."""
    label = QLabel(f"The {what} is not available in this installation.")
    label.setAlignment(Qt.AlignmentFlag.AlignCenter)
    label.setWordWrap(True)
    return label
