"""The one module that touches napari's embedding API.

Everything lfm_studio does with napari's Qt side goes through here, so napari API churn
lands in one place: creating the Qt application the way napari's OpenGL canvas needs it,
probing whether OpenGL works, building a ``napari.qt.QtViewer`` over a bare
``napari.components.ViewerModel`` (with one-time npe2 plugin discovery), grabbing the
canvas and closing it without leaks.

**Callers must call** :func:`prepare_qt_app` **before anything creates the QApplication**
(the studio's ``run_studio``, test fixtures, scripts): Qt only honours
``AA_ShareOpenGLContexts`` when it is set before the application exists, and vispy's
canvases need it when a canvas moves between top-level windows (docking, re-parenting).

Set the environment variable ``LFM_STUDIO_VIEWER=pyqtgraph`` to skip napari entirely
(for example on a machine whose OpenGL driver crashes instead of failing cleanly).

The scene built on it (layers, spaces, views) is :mod:`lfm_studio.widgets.viewer.napari_scene`.
"""

from __future__ import annotations

import logging
import os
import sys
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from qtpy.QtWidgets import QApplication, QWidget

_log = logging.getLogger(__name__)

#: Environment variable that forces the pyqtgraph fallback when set to ``"pyqtgraph"``.
VIEWER_ENV = "LFM_STUDIO_VIEWER"
#: napari theme of the embedded canvas and its controls.
THEME = "dark"
_MIN_GL = (2, 1)  # vispy's gloo needs OpenGL 2.1

_app: QApplication | None = None  # keeps the application object alive
_probe: tuple[bool, str | None] = (False, None)  # (done, reason it failed)
_plugins_discovered = False


def prepare_qt_app(argv: list[str] | None = None, *, name: str = "lfm_studio") -> QApplication:
    """Return the QApplication, creating it with OpenGL context sharing if none exists yet.

    Parameters
    ----------
    argv : list of str, optional
        Command-line arguments for a new application (default: the program name).
    name : str
        Application name of a new application.

    Returns
    -------
    QApplication
        The existing application (unchanged) or a new one with ``AA_ShareOpenGLContexts``.
    """
    global _app
    os.environ.setdefault("QT_API", "pyside6")
    os.environ.setdefault("PYQTGRAPH_QT_LIB", "PySide6")
    from qtpy.QtCore import Qt
    from qtpy.QtWidgets import QApplication

    app = QApplication.instance()
    if app is None:
        QApplication.setAttribute(Qt.ApplicationAttribute.AA_ShareOpenGLContexts, True)
        app = QApplication(list(argv) if argv is not None else sys.argv[:1] or [name])
        app.setApplicationName(name)
    _app = app
    return app


def napari_unavailable_reason() -> str | None:
    """Why the napari canvas cannot be used here, or ``None`` when it can.

    Checks, in order: the ``LFM_STUDIO_VIEWER`` override, that napari imports, and that
    an OpenGL >= 2.1 context can be created and made current on this Qt platform (the
    ``offscreen`` platform cannot). The import and OpenGL results are cached per process.
    Needs a QApplication (see :func:`prepare_qt_app`).
    """
    global _probe
    if os.environ.get(VIEWER_ENV, "").strip().lower() == "pyqtgraph":
        return f"the napari viewer is switched off ({VIEWER_ENV}=pyqtgraph)"
    if not _probe[0]:
        from qtpy.QtGui import QGuiApplication

        if QGuiApplication.instance() is None:
            return "no Qt application yet (call napari_embed.prepare_qt_app() first)"
        _probe = (True, _import_problem() or _opengl_problem())
    return _probe[1]


def _import_problem() -> str | None:
    try:
        import napari
        import napari.qt  # noqa: F401
    except Exception as exc:  # any import-time failure means "no napari here"
        return f"napari could not be imported ({type(exc).__name__}: {exc})"
    return None


def _opengl_problem() -> str | None:
    from qtpy.QtGui import QGuiApplication, QOffscreenSurface, QOpenGLContext

    platform = QGuiApplication.platformName()
    context = QOpenGLContext()
    if not context.create():
        return f"no OpenGL on the Qt platform '{platform}' (could not create an OpenGL context)"
    surface = QOffscreenSurface()
    surface.setFormat(context.format())
    surface.create()
    try:
        if not surface.isValid() or not context.makeCurrent(surface):
            return f"OpenGL context cannot be made current on the Qt platform '{platform}'"
        version = (context.format().majorVersion(), context.format().minorVersion())
        context.doneCurrent()
    finally:
        surface.destroy()
    if version < _MIN_GL:
        return (
            f"OpenGL {version[0]}.{version[1]} is too old (napari needs {_MIN_GL[0]}.{_MIN_GL[1]} or newer)"
        )
    return None


def discover_plugins_once() -> None:
    """Run npe2 plugin discovery once per process (a bare ``ViewerModel`` does not)."""
    global _plugins_discovered
    if _plugins_discovered:
        return
    _plugins_discovered = True
    try:
        from npe2 import PluginManager

        PluginManager.instance().discover()
    except Exception:  # a broken third-party plugin must not take the viewer down
        _log.exception("npe2 plugin discovery failed; continuing without plugins")


def create_qt_viewer(*, theme: str = THEME) -> Any:
    """A new ``napari.qt.QtViewer`` over a new ``ViewerModel`` (the model is ``.viewer``).

    Raises
    ------
    RuntimeError
        When :func:`napari_unavailable_reason` gives a reason (the message says why).
    """
    reason = napari_unavailable_reason()
    if reason is not None:
        raise RuntimeError(f"cannot create the napari viewer: {reason}")
    from napari.components import ViewerModel
    from napari.qt import QtViewer, get_qapp, get_stylesheet

    get_qapp()  # napari's one-time setup of the existing application (theme resource paths)
    discover_plugins_once()
    model = ViewerModel(title="lfm_studio")
    model.theme = theme
    qt_viewer = QtViewer(model, show_welcome_screen=False)
    qt_viewer.setStyleSheet(get_stylesheet(theme))
    return qt_viewer


def layer_controls(qt_viewer: Any) -> tuple[QWidget, QWidget]:
    """napari's layer list and layer controls (contrast, colormap...) for ``qt_viewer``."""
    return qt_viewer.layers, qt_viewer.controls


def themed(widget: QWidget, *, theme: str = THEME) -> QWidget:
    """Apply napari's stylesheet to ``widget`` (for napari widgets placed outside the QtViewer)."""
    from napari.qt import get_stylesheet

    widget.setStyleSheet(get_stylesheet(theme))
    return widget


def canvas_screenshot(qt_viewer: Any) -> np.ndarray:
    """The rendered canvas as a ``(H, W, 4)`` uint8 RGBA array (the widget must be shown)."""
    return qt_viewer.screenshot(flash=False)


def close_qt_viewer(qt_viewer: Any) -> None:
    """Close ``qt_viewer`` for good: stop its animation, delete its canvas (layers go with the model).

    ``QtViewer`` has ``WA_DeleteOnClose``, so the widget is deleted on the next event-loop
    pass; the caller must drop its own references to the viewer and its model. Closing
    twice is harmless.
    """
    if getattr(qt_viewer, "_lfm_closed", False):
        return
    qt_viewer._lfm_closed = True
    # Layers are not removed one by one first: napari runs a full gc.collect() per removal.
    qt_viewer.close()  # closeEvent: dims.stop(), canvas.delete(), layer list close


def flush_deletions() -> None:
    """Process pending ``deleteLater`` calls now (tests and shutdown)."""
    from qtpy.QtCore import QCoreApplication, QEvent

    app = QCoreApplication.instance()
    if app is None:
        return
    for _ in range(3):
        QCoreApplication.sendPostedEvents(None, QEvent.Type.DeferredDelete)
        app.processEvents()


def live_qt_viewers() -> int:
    """How many napari ``QtViewer`` objects are still alive (0 when napari was never imported)."""
    if "napari._qt.qt_viewer" not in sys.modules:
        return 0
    from napari.qt import QtViewer

    return len(QtViewer._instances)  # the registry napari's make_napari_viewer leak check uses
