"""A reconstruction method box and its option fields, built from the engine's registry (qtpy).

:class:`MethodOptions` lists every registered method (:mod:`lfm_studio.engine.reconstruct.registry`)
in a combo box and shows one field per option of any method (spin box for numbers, check box for
true/false, combo box for choices); the fields the chosen method does not take are disabled.
Switching methods moves a field still at the old method's default to the new method's default
(Wiener's SNR 100 -> Tikhonov's 1000) and keeps a value the user typed. The napari plugin and
the studio both use it, so a newly registered method appears in both without editing them.
"""

from __future__ import annotations

from typing import Any

from qtpy.QtCore import Qt, Signal
from qtpy.QtWidgets import QCheckBox, QComboBox, QDoubleSpinBox, QFormLayout, QSpinBox, QWidget

from lfm_studio.engine.reconstruct import registry

FLOAT_DECIMALS = 4
FLOAT_STEP = 10.0**-FLOAT_DECIMALS  # the smallest value above an exclusive lower bound of 0
LARGEST_FLOAT = 1e9  # a number field's upper end when the option has no maximum
LARGEST_INT = 10**6
OFF = "off"  # what an optional number shows at the bottom of its range (None)


def _label(name: str) -> str:
    return {"snr": "SNR", "rtol": "Stop below change", "tv_weight": "TV weight"}.get(
        name, name.replace("_", " ").capitalize()
    )


def _number_field(option: registry.Option) -> QSpinBox | QDoubleSpinBox:
    integer = option.kind is int
    box: QSpinBox | QDoubleSpinBox = QSpinBox() if integer else QDoubleSpinBox()
    step = 1 if integer else FLOAT_STEP
    low = option.minimum if option.minimum is not None else (-LARGEST_INT if integer else -LARGEST_FLOAT)
    high = option.maximum if option.maximum is not None else (LARGEST_INT if integer else LARGEST_FLOAT)
    low = low + step if option.exclusive_minimum else low
    high = high - step if option.exclusive_maximum else high
    if isinstance(box, QDoubleSpinBox):
        box.setDecimals(FLOAT_DECIMALS)
    if option.optional:  # the bottom of the range means None ("off")
        low -= step
        box.setSpecialValueText(OFF)
    box.setRange(int(low) if integer else low, int(high) if integer else high)
    if option.units:
        box.setSuffix(f" {option.units}")
    return box


class MethodOptions(QWidget):
    """Method combo box + option fields (a form). ``exclude`` names options shown elsewhere.

    Signals
    -------
    methodChanged(str) : the chosen method's name.
    """

    methodChanged = Signal(str)  # noqa: N815 - Qt signal names are camelCase

    def __init__(self, *, exclude: tuple[str, ...] = (), parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.method = QComboBox(self)
        for method in registry.methods():
            self.method.addItem(method.label, method.name)
            self.method.setItemData(self.method.count() - 1, method.description, Qt.ToolTipRole)
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
        if index == self.method.currentIndex() and self._current == name:
            return
        self.method.setCurrentIndex(index)
        self._on_method()

    def field(self, name: str) -> QWidget:
        """The field of option ``name``."""
        return self._fields[name]

    def values(self) -> dict[str, Any]:
        """The chosen method's options shown here (the caller adds the excluded ones)."""
        method = registry.get(self.method_name())
        return {o.name: self._value(o.name) for o in method.options if o.name in self._fields}

    # ----- internals -----

    def _make_field(self, option: registry.Option) -> QWidget:
        if option.kind is bool:
            return QCheckBox()
        if option.kind is str:
            box = QComboBox()
            for choice in option.choices or ():
                box.addItem(choice, choice)
            return box
        return _number_field(option)

    def _value(self, name: str) -> Any:
        field, option = self._fields[name], self._options[name]
        if isinstance(field, QCheckBox):
            return field.isChecked()
        if isinstance(field, QComboBox):
            return field.currentData()
        if option.optional and field.value() == field.minimum():
            return None
        return field.value()

    def _set_value(self, name: str, value: Any) -> None:
        field = self._fields[name]
        if isinstance(field, QCheckBox):
            field.setChecked(bool(value))
        elif isinstance(field, QComboBox):
            field.setCurrentIndex(max(0, field.findData(value)))
        else:
            field.setValue(field.minimum() if value is None else value)

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
