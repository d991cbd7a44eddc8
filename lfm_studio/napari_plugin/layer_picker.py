"""A combo box of the viewer's layers that pass a test, kept in step with the layer list."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from qtpy.QtCore import Signal
from qtpy.QtWidgets import QComboBox, QWidget


def unwrapped(layer: Any) -> Any:
    """The layer itself: napari hands plugin widgets its viewer behind a proxy, and layers reached through
    attributes (e.g. ``viewer.layers.selection.active``) come wrapped in new proxy objects, so identity
    (and weak references) must use the wrapped layers."""
    return getattr(layer, "__wrapped__", layer)


def same_layer(a: Any, b: Any) -> bool:
    """Whether ``a`` and ``b`` are the same layer (either may be napari's plugin proxy)."""
    return a is not None and b is not None and unwrapped(a) is unwrapped(b)


class LayerPicker(QComboBox):
    """Pick one of ``viewer``'s layers for which ``accepts(layer)`` is true (by name).

    The list follows layers being added, removed, moved and renamed; the current
    choice is kept while its layer exists. ``preferred(layer)`` ranks layers for the
    default choice (highest first, e.g. our own kind before foreign images).
    ``layerChosen(layer or None)`` is emitted when the chosen layer changes.
    """

    layerChosen = Signal(object)  # noqa: N815 - Qt signal names are camelCase

    def __init__(
        self,
        viewer: Any,
        accepts: Callable[[Any], bool],
        *,
        preferred: Callable[[Any], int] | None = None,
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self._viewer = viewer
        self._accepts = accepts
        self._preferred = preferred
        self._chosen: Any | None = None  # the chosen layer (identity survives renaming)
        events = viewer.layers.events
        for emitter in (events.inserted, events.removed, events.moved, events.renamed):
            emitter.connect(self.refresh)
        self.currentIndexChanged.connect(self._on_index)
        self.refresh()

    def layers(self) -> list[Any]:
        """The acceptable layers, in the viewer's order."""
        return [layer for layer in self._viewer.layers if self._accepts(layer)]

    def refresh(self, *_: Any) -> None:
        """Rebuild the list, keeping the current choice when it still exists."""
        layers = self.layers()
        names = [layer.name for layer in layers]
        if any(same_layer(layer, self._chosen) for layer in layers):
            index = next(i for i, layer in enumerate(layers) if same_layer(layer, self._chosen))
        elif layers:
            rank = self._preferred or (lambda layer: 0)
            index = max(range(len(layers)), key=lambda i: (rank(layers[i]), i))
        else:
            index = -1
        blocked = self.blockSignals(True)
        try:
            self.clear()
            self.addItems(names)
            self.setCurrentIndex(index)
        finally:
            self.blockSignals(blocked)
        self._on_index(index)

    def _on_index(self, _index: int) -> None:
        layer = self.layer()
        unchanged = same_layer(layer, self._chosen) or (layer is None and self._chosen is None)
        if not unchanged:
            self._chosen = layer
            self.layerChosen.emit(layer)

    def layer(self) -> Any | None:
        """The chosen layer (None when there is none)."""
        name = self.currentText()
        return next((layer for layer in self.layers() if layer.name == name), None)

    def set_layer(self, layer: Any) -> None:
        """Choose ``layer`` (it must be one of the choices)."""
        index = self.findText(layer.name)
        if index < 0:
            raise ValueError(f"layer {layer.name!r} is not among the choices {self.names()}.")
        self.setCurrentIndex(index)

    def names(self) -> list[str]:
        """The names offered, in order."""
        return [self.itemText(i) for i in range(self.count())]
