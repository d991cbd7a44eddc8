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

:class:`NapariScene` is the napari half of :class:`~lfm_studio.widgets.psf_viewer.PSFViewer`:
layers by name updated in place, the sensor/sample spaces, 3-D previews of large data,
the slice-plane choice and the depth read-out.
"""

from __future__ import annotations

import logging
import os
import sys
from typing import TYPE_CHECKING, Any

import numpy as np
from psygnal import Signal

if TYPE_CHECKING:
    from qtpy.QtWidgets import QApplication, QWidget

    from lfm_studio.widgets.psf_viewer import DisplayData

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


_PLANES = {"xy": (0, 1, 2), "xz": (1, 0, 2), "yz": (2, 0, 1)}  # order of the last three axes
#: Camera angles (degrees) of a fresh 3-D view: oblique, so depth shows at once.
CAMERA_ANGLES_3D = (0.0, -35.0, 60.0)


class NapariScene:
    """Layers by name on embedded napari canvases, one canvas per space (GUI thread only).

    Sensor-space layers (PSF, light field) and sample-space layers (reconstruction) do not
    share a world, so each space has its own ``QtViewer`` (the sample one is created on
    first use) in a stacked widget: switching space is instant, and each canvas's
    sliders span its own layers. Layers are never removed to switch (napari runs a full
    garbage collection on every removal).

    Parameters
    ----------
    max_voxels_3d : int
        Largest displayed 3-D block drawn at full resolution in 3-D; larger ones are drawn
        from a laterally max-pooled preview (2-D slices always use the full data).
    """

    depth_changed = Signal(object)  # depth in um (sample side) of the focused layer's slice, or None

    def __init__(self, *, max_voxels_3d: int) -> None:
        from qtpy.QtWidgets import QStackedWidget

        self._budget = max_voxels_3d
        self._views: dict[str, Any] = {}  # space -> QtViewer
        self._layers: dict[str, Any] = {}
        self._shown: dict[str, DisplayData] = {}
        self._previews: dict[str, tuple[np.ndarray, int] | None] = {}
        self.focused: str | None = None
        self.widget, self.panel = QStackedWidget(), QStackedWidget()
        self.panel.setMinimumWidth(300)  # napari controls are unreadable narrower
        self._space = "sensor"
        self._view("sensor")

    @property
    def qt_viewer(self) -> Any:
        """The ``QtViewer`` on screen."""
        return self._views[self._space]

    @property
    def model(self) -> Any:
        """The ``ViewerModel`` on screen."""
        return self.qt_viewer.viewer

    def _view(self, space: str) -> Any:
        if space not in self._views:
            from qtpy.QtCore import Qt
            from qtpy.QtWidgets import QSplitter

            qt_viewer = self._views[space] = create_qt_viewer()
            model = qt_viewer.viewer
            overlays = model.canvas.overlays
            overlays.text.update({"visible": True, "position": "top_left", "font_size": 10, "color": "white"})
            overlays.scale_bar.update({"visible": True, "box": False})
            model.dims.events.current_step.connect(self._on_step)
            model.dims.events.order.connect(self._on_step)
            model.dims.events.ndisplay.connect(self._on_ndisplay)
            if self._views.keys() - {space}:  # same 2-D / 3-D mode as the others
                model.dims.ndisplay = next(iter(self._views.values())).viewer.dims.ndisplay
            self.widget.addWidget(qt_viewer)
            panel = QSplitter(Qt.Orientation.Vertical)
            for part in layer_controls(qt_viewer):
                panel.addWidget(part)
            self.panel.addWidget(themed(panel))
        return self._views[space]

    # -- layers ---------------------------------------------------------------------------
    def put(self, shown: DisplayData) -> bool:
        """Show ``shown`` in the layer of its name (created if needed); True when created."""
        from napari.layers import Image

        layer = self._layers.get(shown.name)
        if layer is not None and (layer.ndim != shown.data.ndim or layer.metadata["space"] != shown.space):
            self._drop(shown.name)  # 3-D <-> 5-D PSF: the one case that needs a new layer
            layer = None
        created = layer is None
        self._shown[shown.name] = shown
        self._previews.pop(shown.name, None)
        auto = shown.contrast_limits is None
        if created:
            layer = Image(
                shown.data,
                name=shown.name,
                scale=shown.scale_um,
                translate=shown.translate_um,
                affine=_stretch(shown),
                colormap=shown.colormap,
                contrast_limits=shown.contrast_limits,
                auto_contrast=auto,
                axis_labels=shown.axis_labels,
                units=_units(shown),
                blending="additive",
                metadata=self._metadata(shown, 1),
            )
            layer.bounding_box.update({"points": False, "line_color": "#8c8c8c"})  # drawn in 3-D only
            self._layers[shown.name] = layer
            self._view(shown.space).viewer.layers.append(layer)
        else:
            layer.affine = _stretch(shown)
            if not auto:
                layer.auto_contrast = False
                layer.contrast_limits_range = shown.contrast_limits
                layer.contrast_limits = shown.contrast_limits
        self._set_resolution(shown.name, force=True)
        if auto:  # slider range over the whole stack, limits per slice (napari's "continuous")
            low, high = float(shown.data.min()), float(shown.data.max())
            layer.contrast_limits_range = (low, high if high > low else low + 1.0)
            layer.auto_contrast = True
        if created:
            self.focus(shown.name)
            dims = self.model.dims
            for axis, step in shown.initial_step.items():
                dims.set_current_step(axis + dims.ndim - shown.data.ndim, step)
        elif shown.name == self.focused:
            self._on_step()
        return created

    def focus(self, name: str, *, reset: bool = True) -> None:
        """Put ``name``'s space on screen and show ``name`` alone in it (selected for the controls)."""
        target = self._layers[name]
        self._space = space = target.metadata["space"]
        self.widget.setCurrentWidget(self.qt_viewer)
        self.panel.setCurrentIndex(self.widget.currentIndex())
        for other_name, layer in self._layers.items():
            if layer.metadata["space"] == space:
                layer.visible = other_name == name
        self.model.layers.selection.active = target
        self.focused = name
        if reset:
            self.reset_view()
        self._on_step()

    def names(self) -> list[str]:
        return list(self._layers)

    def layer(self, name: str) -> Any:
        return self._layers.get(name)

    def shown(self, name: str | None) -> DisplayData | None:
        """What ``name`` shows at full resolution (data, sampling in um, metadata)."""
        return self._shown.get(name) if name else None

    def clear(self) -> None:
        for qt_viewer in self._views.values():
            qt_viewer.viewer.layers.clear()
        self._layers.clear()
        self._shown.clear()
        self._previews.clear()
        self.focused = None
        self._on_step()

    def _drop(self, name: str) -> None:
        layer = self._layers.pop(name)
        self._views[layer.metadata["space"]].viewer.layers.remove(layer)
        self._shown.pop(name, None)
        self._previews.pop(name, None)

    # -- view -----------------------------------------------------------------------------
    def set_3d(self, on: bool) -> None:
        for qt_viewer in self._views.values():
            qt_viewer.viewer.dims.ndisplay = 3 if on else 2

    def set_plane(self, plane: str) -> None:
        """Slice plane of the 2-D view: ``"xy"``, ``"xz"`` (rows = depth) or ``"yz"``."""
        if plane not in _PLANES:
            raise ValueError(f"plane must be one of {sorted(_PLANES)}; got {plane!r}.")
        for qt_viewer in self._views.values():
            dims = qt_viewer.viewer.dims
            if dims.ndim >= 3:
                dims.order = tuple(range(dims.ndim - 3)) + tuple(dims.ndim - 3 + i for i in _PLANES[plane])
        self.reset_view()

    def reset_view(self) -> None:
        """Fit the layers on screen; in 3-D from an oblique angle so depth shows at once."""
        if self.model.dims.ndisplay == 3:
            self.model.scene.camera.angles = CAMERA_ANGLES_3D
            self.model.reset_view(reset_camera_angle=False)
        else:
            self.model.reset_view()

    def screenshot(self) -> np.ndarray:
        return canvas_screenshot(self.qt_viewer)

    def close(self) -> None:
        for qt_viewer in self._views.values():
            events = qt_viewer.viewer.dims.events
            events.current_step.disconnect(self._on_step)
            events.order.disconnect(self._on_step)
            events.ndisplay.disconnect(self._on_ndisplay)
            close_qt_viewer(qt_viewer)
        self._views.clear()
        self._layers.clear()
        self._shown.clear()
        self._previews.clear()
        self.focused = None

    # -- internals ------------------------------------------------------------------------
    def _metadata(self, shown: DisplayData, factor: int) -> dict[str, Any]:
        return {
            **shown.metadata,
            "scale_um": shown.scale_um,
            "z_stretch": shown.z_stretch,
            "preview_factor": factor,
        }

    def _set_resolution(self, name: str, *, force: bool = False) -> None:
        """Full data in 2-D; in 3-D a max-pooled preview when the data is over budget."""
        from lfm_studio.widgets.psf_viewer import max_pool_preview

        layer, shown = self._layers[name], self._shown[name]
        factor, data = 1, shown.data
        if self._views[shown.space].viewer.dims.ndisplay == 3 and shown.has_depth:
            if name not in self._previews:
                self._previews[name] = max_pool_preview(shown.data, self._budget)
            if self._previews[name] is not None:
                data, factor = self._previews[name]
        if not force and layer.metadata.get("preview_factor") == factor:
            return
        scale, translate = np.array(shown.scale_um), np.array(shown.translate_um)
        translate[-2:] += (factor - 1) / 2 * scale[-2:]  # pooled pixel centres
        scale[-2:] *= factor
        layer.metadata = self._metadata(shown, factor)
        layer.scale, layer.translate = scale, translate
        layer.data = data

    def _on_ndisplay(self, event: Any = None) -> None:
        for name, layer in self._layers.items():
            self._set_resolution(name)
            three_d = self._views[layer.metadata["space"]].viewer.dims.ndisplay == 3
            layer.bounding_box.visible = three_d and self._shown[name].has_depth
        self.reset_view()
        self._on_step()

    def _on_step(self, event: Any = None) -> None:
        """Refresh the read-out (layer, slice position in um, preview note); emit ``depth_changed``."""
        shown = self._shown.get(self.focused) if self.focused else None
        depth, parts = None, [shown.name] if shown else []
        if shown is not None:
            dims, ndim = self.model.dims, shown.data.ndim
            offset = dims.ndim - ndim
            axes = {"x": ndim - 1, "y": ndim - 2} | ({"z": shown.z_axis} if shown.has_depth else {})
            sliced = [(n, a) for n, a in axes.items() if a + offset not in dims.displayed]
            if dims.ndisplay == 3 and shown.z_stretch != 1:
                parts.append(f"depth axis drawn ×{shown.z_stretch:g}")
            for label, axis in sliced[:1]:
                value = dims.point[axis + offset] / (shown.z_stretch if label == "z" else 1.0)
                depth = value if label == "z" else None
                parts.append(f"{label} = {value:+.1f} µm")
            factor = self._layers[shown.name].metadata.get("preview_factor", 1)
            if factor > 1:
                parts.append(f"3-D preview: max of {factor}×{factor} pixels")
        self.model.canvas.overlays.text.text = "   ".join(parts)
        self.depth_changed.emit(depth)


def _stretch(shown: DisplayData) -> np.ndarray:
    """Affine (ndim+1 square) that multiplies the depth axis by ``shown.z_stretch``."""
    affine = np.eye(shown.data.ndim + 1)
    if shown.has_depth:
        affine[shown.z_axis, shown.z_axis] = shown.z_stretch
    return affine


def _units(shown: DisplayData) -> tuple[str, ...]:
    spatial = 3 if shown.has_depth else 2
    return ("pixel",) * (shown.data.ndim - spatial) + ("um",) * spatial
