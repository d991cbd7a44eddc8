"""``NapariScene``: the napari half of :class:`~lfm_studio.widgets.psf_viewer.PSFViewer`.

Layers by name, updated in place, on one embedded canvas per space (sensor, sample); the
slice-plane choice, the 3-D camera and the read-out of the slice position. Large data is
shown as a napari multiscale layer over its max-pooled pyramid
(:func:`~lfm_studio.widgets.viewer.display_data.pyramid_levels`): napari draws 2-D views from
the level that matches the zoom (full data when zoomed in) and 3-D views from the
coarsest level. Canvas creation and clean-up go through :mod:`lfm_studio.widgets.viewer.napari_embed`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from psygnal import Signal

from lfm_studio.widgets.viewer.display_data import SAMPLE, depth_axis_um, nearest_depth_index
from lfm_studio.widgets.viewer.napari_embed import (
    canvas_screenshot,
    close_qt_viewer,
    create_qt_viewer,
    layer_controls,
    themed,
)

if TYPE_CHECKING:
    from lfm_studio.widgets.viewer.display_data import DisplayData

MIP_BY_DEFAULT = (SAMPLE,)  # spaces whose 2-D views start as a maximum-intensity projection
_PLANES = {"xy": (0, 1, 2), "xz": (1, 0, 2), "yz": (2, 0, 1)}  # order of the last three axes
#: Camera angles (degrees) of a fresh 3-D view: oblique, so depth shows at once.
CAMERA_ANGLES_3D = (0.0, -35.0, 60.0)
STALE_COLOR = "#ffb74d"  # the canvas read-out while the focused layer is out of date


class NapariScene:
    """Layers by name on embedded napari canvases, one canvas per space (GUI thread only).

    Sensor-space layers (PSF, light field) and sample-space layers (reconstruction) do not
    share a world, so each space has its own ``QtViewer`` (the sample one is created on
    first use) in a stacked widget: switching space is instant, and each canvas's
    sliders span its own layers. Layers are never removed to switch (napari runs a full
    garbage collection on every removal).

    Data with pyramid levels (:attr:`DisplayData.levels`) becomes a multiscale layer.
    """

    depth_changed = Signal(object)  # depth in um (sample side) of the focused layer's slice, or None

    def __init__(self) -> None:
        from qtpy.QtWidgets import QStackedWidget

        self._views: dict[str, Any] = {}  # space -> QtViewer
        self._layers: dict[str, Any] = {}
        self._shown: dict[str, DisplayData] = {}
        self.focused: str | None = None
        # Spaces whose 2-D views show the maximum-intensity projection over depth. Sample volumes
        # (phantom, reconstruction: sparse beads) start projected, since one slice holds few beads;
        # PSFs and camera images start on one slice.
        self._mip_spaces: set[str] = set(MIP_BY_DEFAULT)
        self._stale_note = ""  # appended to the canvas read-out while the focused layer is out of date
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
        """Show ``shown`` in the layer of its name (created if needed); True when created.

        A layer that cannot take the new data in place (3-D <-> 5-D PSF, a pyramid of another
        depth: the 5-depth preview followed by the full stack) is replaced by a new one, which
        inherits the focus. The bookkeeping (``_layers``, ``_shown``, ``focused``) is kept
        consistent before napari is told, because napari emits dims events (and so calls
        :meth:`_on_step`) from inside ``layers.remove`` / ``layers.append``.

        New data for an existing layer with depth keeps the depth its canvas stood at (the
        nearest slice of the new data), replaced or updated in place.
        """
        from napari.layers import Image

        kept = self._depth_on_screen(shown.name)  # before napari moves the slider for the new data
        layer = self._layers.get(shown.name)
        multiscale = bool(shown.levels)
        refocus = replaced = False
        if layer is not None and (
            layer.ndim != shown.data.ndim
            or layer.metadata["space"] != shown.space
            or layer.multiscale != multiscale
            or (multiscale and len(layer.data) != len(shown.pyramid))
        ):
            refocus = self.focused == shown.name
            self._drop(shown.name)
            layer, replaced = None, True
        created = layer is None
        auto = shown.contrast_limits is None
        data = shown.pyramid if multiscale else shown.data
        if created:
            layer = Image(
                data,
                multiscale=multiscale,
                name=shown.name,
                scale=shown.scale_um,
                translate=shown.translate_um,
                affine=_stretch(shown),
                colormap=shown.colormap,
                contrast_limits=shown.contrast_limits or shown.data_range,
                gamma=shown.gamma,
                auto_contrast=auto,
                axis_labels=shown.axis_labels,
                units=_units(shown),
                blending="additive",
                metadata=self._metadata(shown),
            )
            layer.bounding_box.update({"points": False, "line_color": "#8c8c8c"})  # drawn in 3-D only
            self._layers[shown.name], self._shown[shown.name] = layer, shown
            self._view(shown.space).viewer.layers.append(layer)
        else:
            self._shown[shown.name] = shown
            layer.metadata = self._metadata(shown)
            layer.scale, layer.translate = shown.scale_um, shown.translate_um
            layer.affine = _stretch(shown)
            layer.data = data
            layer.gamma = shown.gamma
        layer.contrast_limits_range = _slider_range(shown)  # the slider spans the whole data
        if auto:  # limits per slice (napari's "continuous")
            layer.auto_contrast = True
        else:
            layer.auto_contrast = False
            layer.contrast_limits = shown.contrast_limits
        layer.projection_mode = "max" if shown.space in self._mip_spaces and shown.has_depth else "none"
        self._apply_mip(shown.space)
        if created and (refocus or not replaced or self.focused is None):  # else: stays hidden
            self.focus(shown.name)
            dims = self.model.dims
            for axis, step in shown.initial_step.items():
                dims.set_current_step(axis + dims.ndim - shown.data.ndim, step)
        elif shown.name == self.focused:
            self._on_step()
        elif created:
            layer.visible = False  # another layer of its space is on screen
        if kept is not None and shown.has_depth and shown.space == kept[0]:
            self._show_depth(shown, kept[1])
        return created

    def _depth_axis(self, shown: DisplayData) -> int:
        """The depth axis of ``shown`` in its canvas's dims."""
        dims = self._views[shown.space].viewer.dims
        return shown.z_axis + dims.ndim - shown.data.ndim

    def _depth_on_screen(self, name: str) -> tuple[str, float] | None:
        """``(space, depth in um)`` of the slice at which layer ``name``'s canvas stands, or None
        (no such layer, or one without depth)."""
        shown = self._shown.get(name)
        if shown is None or not shown.has_depth:
            return None
        dims = self._views[shown.space].viewer.dims
        return shown.space, float(dims.point[self._depth_axis(shown)]) / shown.z_stretch

    def _show_depth(self, shown: DisplayData, depth_um: float) -> None:
        """Put ``shown``'s canvas on the slice of ``shown`` nearest ``depth_um`` (sample side).

        A stack replacing another (the 5-depth preview, then the full stack) keeps the depth on
        screen: updating the layer's scale before its data clipped the slider to the old depth
        span (the conventional preview's z = 0 became z = -80 um in the full stack).
        """
        depth = depth_axis_um(shown)[nearest_depth_index(shown, depth_um)]
        self._views[shown.space].viewer.dims.set_point(self._depth_axis(shown), depth * shown.z_stretch)
        self._on_step()  # the read-out: a point moved within one step leaves current_step as it was

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
        self.focused = None
        self._on_step()

    def _drop(self, name: str) -> None:
        """Remove layer ``name``: forget it (and its focus) first, then detach it from napari."""
        layer = self._layers.pop(name)
        self._shown.pop(name, None)
        if self.focused == name:
            self.focused = None
        self._views[layer.metadata["space"]].viewer.layers.remove(layer)

    # -- view -----------------------------------------------------------------------------
    @property
    def mip(self) -> bool:
        """Whether the 2-D view of the space on screen shows the maximum-intensity projection over depth."""
        return self._space in self._mip_spaces

    def set_mip(self, on: bool) -> None:
        """Maximum-intensity projection over depth for the layers with a depth axis of the space on screen
        (2-D views; each space keeps its own choice).

        napari's thick slicing: the depth margins of each canvas cover the whole stack and the
        layers project with ``"max"``. 3-D views render a MIP anyway.
        """
        if on:
            self._mip_spaces.add(self._space)
        else:
            self._mip_spaces.discard(self._space)
        for name, layer in self._layers.items():
            if layer.metadata["space"] == self._space:
                layer.projection_mode = "max" if on and self._shown[name].has_depth else "none"
        if self._space in self._views:
            self._apply_mip(self._space)
        self._on_step()

    def _apply_mip(self, space: str) -> None:
        """Depth margins of ``space``'s canvas: the full depth extent with MIP on, zero otherwise."""
        dims = self._views[space].viewer.dims
        deep = [self._shown[n] for n, layer in self._layers.items() if layer.metadata["space"] == space]
        if dims.ndim < 3 or not any(shown.has_depth for shown in deep):
            return
        axis = dims.ndim - 3
        world = dims.range[axis]
        extent = 2.0 * (world.stop - world.start) + world.step if space in self._mip_spaces else 0.0
        if dims.thickness[axis] != extent:
            thickness = list(dims.thickness)
            thickness[axis] = extent
            dims.thickness = tuple(thickness)

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
        self.focused = None

    # -- internals ------------------------------------------------------------------------
    def _metadata(self, shown: DisplayData) -> dict[str, Any]:
        return {
            **shown.metadata,
            "scale_um": shown.scale_um,
            "z_stretch": shown.z_stretch,
            "pyramid_factors": [shown.level_factor(k) for k in range(len(shown.pyramid))],
        }

    def _on_ndisplay(self, event: Any = None) -> None:
        for name, layer in self._layers.items():
            three_d = self._views[layer.metadata["space"]].viewer.dims.ndisplay == 3
            layer.bounding_box.visible = three_d and self._shown[name].has_depth
        self.reset_view()
        self._on_step()

    def set_stale_note(self, note: str) -> None:
        """Show ``note`` (e.g. ``"STALE (PSF failed)"``) in the canvas read-out, in amber; ``""`` clears it."""
        if note != self._stale_note:
            self._stale_note = note
            self._on_step()

    def drawn_factor(self, name: str) -> int:
        """Lateral max-pooling factor of what 3-D rendering draws for ``name`` (napari renders a
        multiscale layer from its coarsest level in 3-D); 1 in 2-D views, whose level follows the zoom."""
        layer, shown = self._layers[name], self._shown[name]
        three_d = self._views[shown.space].viewer.dims.ndisplay == 3
        return shown.level_factor(len(shown.pyramid) - 1) if three_d and layer.multiscale else 1

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
                if label == "z" and shown.space in self._mip_spaces and dims.ndisplay == 2:
                    parts.append("maximum over all depths (MIP)")
                    continue
                value = dims.point[axis + offset] / (shown.z_stretch if label == "z" else 1.0)
                depth = value if label == "z" else None
                parts.append(f"{label} = {position_text(value)}")
            factor = self.drawn_factor(shown.name)
            if factor > 1:
                parts.append(f"3-D preview: max of {factor}×{factor} pixels")
        if self._stale_note and shown is not None:
            parts.append(self._stale_note)
        overlay = self.model.canvas.overlays.text
        overlay.color = STALE_COLOR if self._stale_note and shown is not None else "white"
        overlay.text = "   ".join(parts)
        self.depth_changed.emit(depth)


def position_text(value_um: float) -> str:
    """A slice position for the read-out: ``+12.5 µm``; a value that rounds to zero is ``+0.0 µm``, never ``-0.0``."""
    return f"{round(value_um, 1) + 0.0:+.1f} µm"


def _slider_range(shown: DisplayData) -> tuple[float, float]:
    """The contrast slider's range: the data range, widened to hold fixed limits."""
    low, high = shown.data_range
    if shown.contrast_limits is not None:
        low, high = min(low, shown.contrast_limits[0]), max(high, shown.contrast_limits[1])
    return (low, high)


def _stretch(shown: DisplayData) -> np.ndarray:
    """Affine (ndim+1 square) that multiplies the depth axis by ``shown.z_stretch``."""
    affine = np.eye(shown.data.ndim + 1)
    if shown.has_depth:
        affine[shown.z_axis, shown.z_axis] = shown.z_stretch
    return affine


def _units(shown: DisplayData) -> tuple[str, ...]:
    spatial = 3 if shown.has_depth else 2
    return ("pixel",) * (shown.data.ndim - spatial) + ("um",) * spatial
