"""A reconstruction method box and its option fields, built from the engine's registry (qtpy).

:class:`MethodOptions` lists every registered method (:mod:`lfm_studio.engine.reconstruct.registry`)
in a combo box and shows one field per option of any method (:class:`NumericField` for numbers,
check box for true/false, combo box for choices, a path with a browse button for a file); the fields the chosen method does not take are disabled.
Switching methods moves a field still at the old method's default to the new method's default
(Wiener's SNR 100 -> Tikhonov's 1000) and keeps a value the user typed. The napari plugin and
the studio both use it, so a newly registered method appears in both without editing them.
"""

from __future__ import annotations

from typing import Any

from qtpy.QtCore import Qt, Signal
from qtpy.QtWidgets import (
    QCheckBox,
    QComboBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLineEdit,
    QToolButton,
    QWidget,
)

from lfm_studio.engine.reconstruct import registry
from lfm_studio.engine.systems.kinds import SystemKind
from lfm_studio.widgets.numeric_field import NumericField
from lfm_studio.widgets.numeric_text import NumberRule

LARGEST = 1e9  # a number field's upper end (lower: minus it) when the option has no bound
LARGEST_INT = 10**6
EXCLUSIVE_MARGIN = 1e-12  # relative: how far inside an exclusive bound a field's range ends
OFF = "off"  # what an optional number shows at the bottom of its range (None)


def _label(name: str) -> str:
    return {"snr": "SNR", "rtol": "Stop below change", "tv_weight": "TV weight"}.get(
        name, name.replace("_", " ").capitalize()
    )


def _inside(bound: float, direction: int) -> float:
    return bound + direction * EXCLUSIVE_MARGIN * max(abs(bound), 1.0)


def number_rule(option: registry.Option) -> NumberRule:
    """The :class:`NumberRule` of a number option: its bounds (exclusive ones moved just inside, missing
    ones at +-1e9, +-1e6 for integers), units, and ``"off"`` at the bottom for an optional one (None)."""
    integer = option.kind is int
    largest = LARGEST_INT if integer else LARGEST
    low = -largest if option.minimum is None else option.minimum
    high = largest if option.maximum is None else option.maximum
    if option.exclusive_minimum:
        low = low + 1 if integer else _inside(low, +1)
    if option.exclusive_maximum:
        high = high - 1 if integer else _inside(high, -1)
    special = ""
    if option.optional:  # one step below the range means None
        low, special = low - (1 if integer else EXCLUSIVE_MARGIN * max(abs(low), 1.0)), OFF
    return NumberRule(
        _label(option.name), low, high, option.units, integer=integer, special_text=special,
        example=None if option.default is None else option.default,
    )  # fmt: skip


class MethodOptions(QWidget):
    """Method combo box + option fields (a form). ``exclude`` names options shown elsewhere.

    Signals
    -------
    methodChanged(str) : the chosen method's name.
    edited() : the user changed the method or an option (not emitted by :meth:`display`).
    """

    methodChanged = Signal(str)  # noqa: N815 - Qt signal names are camelCase
    edited = Signal()

    def __init__(self, *, exclude: tuple[str, ...] = (), parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.method = QComboBox(self)
        for method in registry.methods():
            self.method.addItem(method.label, method.name)
            self.method.setItemData(self.method.count() - 1, method.description, Qt.ItemDataRole.ToolTipRole)
        self.form = QFormLayout(self)
        self.form.setContentsMargins(0, 0, 0, 0)
        self.form.addRow("Method", self.method)
        self._options = {n: o for n, o in registry.all_options().items() if n not in exclude}
        self._fields: dict[str, QWidget] = {}
        for name, option in self._options.items():
            field = self._make_field(option)
            field.setToolTip(option.help)
            self._fields[name] = field
            self.form.addRow(_label(name), field)
            _change_signal(field).connect(self._on_field_edited)
        self._current = ""
        self.set_method(registry.default_method())
        self.method.currentIndexChanged.connect(self._on_method)

    # ----- the contract -----

    def method_name(self) -> str:
        """The chosen method's name."""
        return str(self.method.currentData())

    def set_method(self, name: str) -> None:
        """Choose the method ``name``; a ``ValueError`` naming the registered ones otherwise."""
        registry.get(name)  # the named error for an unknown name
        index = self.method.findData(name)
        if index < 0:
            raise ValueError(
                f"method {name!r} was registered after this form was built. Fix: reopen the widget."
            )
        self.method.setCurrentIndex(index)  # runs _on_method unless signals are blocked
        if self._current != name:
            self._on_method()

    def restrict_to_kind(self, kind: SystemKind) -> None:
        """Offer only the methods that reconstruct a design of ``kind``: the others stay listed but
        disabled, their tooltip saying why. A chosen method that no longer fits is replaced by the
        default method (or the first that fits), which emits ``methodChanged`` and ``edited``."""
        for index in range(self.method.count()):
            method = registry.get(self.method.itemData(index))
            fits = method.supports_kind(kind)
            self.method.model().item(index).setEnabled(fits)
            tip = (
                method.description if fits else f"Not for a {kind.title} design: it needs a {method.needs()}."
            )
            self.method.setItemData(index, tip, Qt.ItemDataRole.ToolTipRole)
        if not registry.get(self.method_name()).supports_kind(kind):
            fitting = [m.name for m in registry.methods() if m.supports_kind(kind)]
            default = registry.default_method()
            self.set_method(default if default in fitting else fitting[0])

    def field(self, name: str) -> QWidget:
        """The field of option ``name`` (one of :meth:`option_names`)."""
        if name not in self._fields:
            raise ValueError(f"no field for the option {name!r}; the fields are {self.option_names()}.")
        return self._fields[name]

    def option_names(self) -> tuple[str, ...]:
        """The options shown here, in form order."""
        return tuple(self._fields)

    def fields(self) -> tuple[QWidget, ...]:
        """Every option field, in form order."""
        return tuple(self._fields.values())

    def numeric_fields(self) -> tuple[NumericField, ...]:
        """The typed numbers among :meth:`fields` (for ``commit_all`` and error labels)."""
        return tuple(f for f in self._fields.values() if isinstance(f, NumericField))

    def display(self, method: str, values: dict[str, Any]) -> None:
        """Show ``method`` with ``values`` (others at its defaults) without emitting any signal."""
        blocked = (self, self.method, *self._fields.values())
        for widget in blocked:
            widget.blockSignals(True)
        try:
            self.set_method(method)
            for name, value in values.items():
                if name in self._fields:
                    self._set_value(name, value)
        finally:
            for widget in blocked:
                widget.blockSignals(False)

    def values(self) -> dict[str, Any]:
        """The chosen method's options shown here (the caller adds the excluded ones)."""
        method = registry.get(self.method_name())
        return {o.name: self._value(o.name) for o in method.options if o.name in self._fields}

    # ----- internals -----

    def _make_field(self, option: registry.Option) -> QWidget:
        if option.kind is bool:
            return QCheckBox()
        if option.kind is str and option.file_filter is not None:
            return PathField(option.file_filter)
        if option.kind is str:
            box = QComboBox()
            for choice in option.choices or ():
                box.addItem(choice, choice)
            return box
        return NumericField(number_rule(option), option.default, step=1 if option.kind is int else 0.0)

    def _value(self, name: str) -> Any:
        field, option = self._fields[name], self._options[name]
        if isinstance(field, QCheckBox):
            return field.isChecked()
        if isinstance(field, QComboBox):
            return field.currentData()
        if isinstance(field, PathField):
            return field.value()
        assert isinstance(field, NumericField)
        if option.optional and field.value() <= field.rule.minimum:
            return None
        return field.value()

    def _set_value(self, name: str, value: Any) -> None:
        field = self._fields[name]
        if isinstance(field, QCheckBox):
            field.setChecked(bool(value))
        elif isinstance(field, QComboBox):
            field.setCurrentIndex(max(0, field.findData(value)))
        elif isinstance(field, PathField):
            field.setValue(None if value is None else str(value))
        elif isinstance(field, NumericField):
            field.setValue(field.rule.minimum if value is None else value)

    def _on_method(self, *_: Any) -> None:
        new = registry.get(self.method_name())
        old = registry.get(self._current) if self._current in registry.names() else None
        for name, field in self._fields.items():
            option = new.option(name)
            field.setEnabled(option is not None)
            if option is None:
                continue
            before = None if old is None else old.option(name)
            untouched = before is None or self._value(name) == before.default
            if old is None or untouched:
                self._set_value(name, option.default)
        self._current = new.name
        self.methodChanged.emit(new.name)
        self.edited.emit()

    def _on_field_edited(self, *_: Any) -> None:
        self.edited.emit()


class PathField(QWidget):
    """A file path typed or picked with a browse button (a ``str`` option with a ``file_filter``);
    ``committed`` when editing ends or a file is picked. An empty field is None."""

    committed = Signal()

    def __init__(self, file_filter: str, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.file_filter = file_filter
        self.line = QLineEdit()
        self.line.setPlaceholderText("none")
        self.line.editingFinished.connect(self.committed)
        browse = QToolButton()
        browse.setText("…")
        browse.setToolTip(f"Choose a file ({file_filter})")
        browse.clicked.connect(self._browse)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.line, 1)
        layout.addWidget(browse)

    def value(self) -> str | None:
        text = self.line.text().strip()
        return text or None

    def setValue(self, value: str | None) -> None:
        self.line.setText(value or "")

    def _browse(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Choose a file", self.line.text(), self.file_filter)
        if path:
            self.setValue(path)
            self.committed.emit()


def _change_signal(field: QWidget) -> Any:
    """The signal ``field`` emits when its value changes."""
    for name in ("committed", "toggled", "currentIndexChanged"):
        signal = getattr(field, name, None)
        if signal is not None:
            return signal
    raise TypeError(f"{type(field).__name__} has no value-change signal")
