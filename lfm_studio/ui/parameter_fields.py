"""The editable design parameters of the parameter panel and the input widget of one of them.

Each :class:`FieldSpec` (:mod:`lfm_studio.ui.field_specs`, Qt-free) names a design value by its
path (as in :func:`~lfm_studio.engine.design.evolve`), the unit shown and the input range. Ranges
are deliberately wider than what is physically valid, so that a wrong value reaches
the design checks and comes back with their reason (NA above the immersion index,
quantum efficiency above 1, ...) instead of being silently clamped.
"""

from __future__ import annotations

from qtpy.QtCore import Signal
from qtpy.QtWidgets import QHBoxLayout, QLabel, QWidget

from lfm_studio.ui.field_specs import FIELDS as FIELDS  # re-exported: the panel's fields
from lfm_studio.ui.field_specs import FieldSpec
from lfm_studio.widgets.numeric_field import NumericField
from lfm_studio.widgets.numeric_text import NumberRule


class QuantityInput(QWidget):
    """One or two :class:`~lfm_studio.widgets.numeric_field.NumericField` for a :class:`FieldSpec`.

    ``edited(path)`` when a valid number is committed (Enter, leaving the box, an arrow
    step); ``refused(path, reason)`` when the text typed is not a number in range (the
    design in force does not change, the text stays to be corrected).
    """

    edited = Signal(str)  # the field path
    refused = Signal(str, str)  # the field path, the reason

    def __init__(self, spec: FieldSpec, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.spec = spec
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self.boxes: list[NumericField] = []
        for index in range(spec.parts):
            name = spec.label
            if spec.parts == 2:
                name = f"{spec.label} {'yx'[index] if spec.integer else ('from', 'to')[index]}"
            rule = NumberRule(
                name, spec.minimum, spec.maximum, spec.unit, integer=spec.integer,
                special_text="none" if spec.optional else "",
            )  # fmt: skip
            box = NumericField(rule, step=spec.step, tip=spec.tip, parent=self)
            box.committed.connect(self._on_committed)
            box.refused.connect(self._on_refused)
            layout.addWidget(box, 1)
            self.boxes.append(box)
        self.setToolTip(spec.tip)

    def _on_committed(self, _value: object) -> None:
        self.edited.emit(self.spec.path)

    def _on_refused(self, reason: str) -> None:
        self.refused.emit(self.spec.path, reason)

    def error(self) -> str | None:
        """Why a typed text was refused (the first box with one), None when every box holds a number."""
        return next((box.error() for box in self.boxes if box.error() is not None), None)

    def value(self):
        """The value as the design stores it (a number, a pair, or None for an optional "none")."""
        values = [box.value() for box in self.boxes]
        if self.spec.optional and values[0] <= self.spec.minimum:
            return None
        return tuple(values) if self.spec.parts == 2 else values[0]

    def set_value(self, value) -> None:
        """Show ``value`` without emitting ``edited`` (state -> view)."""
        values = (value,) if self.spec.parts == 1 else tuple(value)
        for box, v in zip(self.boxes, values, strict=True):
            box.setValue(self.spec.minimum if v is None else v)

    def discard_edits(self) -> None:
        """Drop refused texts (the document was replaced)."""
        for box in self.boxes:
            box.discard_edit()

    def set_invalid(self, message: str | None) -> None:
        """Red border and the reason as tooltip for a value the design refused (None: valid again)."""
        self.setProperty("invalid", message is not None)
        for box in self.boxes:
            box.set_invalid(message)


class ErrorLabel(QLabel):
    """The reason a field's value was refused, shown right under the field (hidden when valid)."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWordWrap(True)
        self.setStyleSheet("color: #d32f2f;")
        self.setVisible(False)

    def show_error(self, message: str | None) -> None:
        self.setText(message or "")
        self.setVisible(bool(message))
