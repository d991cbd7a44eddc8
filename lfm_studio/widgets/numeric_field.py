"""The one numeric input of the studio and its napari widgets: a line edit with one parsing policy.

:class:`NumericField` shows the value in force with its unit and the locale's decimal
mark. What the user types is parsed by :func:`~lfm_studio.widgets.numeric_text.parse_number`
only when it is committed (Enter, leaving the field); nothing is dropped or clamped
while typing. A valid commit puts the value in force and emits ``committed(value)``;
anything else leaves the previous value in force, keeps the text so it can be
corrected, draws a red border, puts the reason in the tooltip and emits
``refused(reason)`` for the host to show next to the field. Up/Down (and Page Up/Down,
x10) step the value within the range.

A host can also mark the field invalid for a reason of its own (the design checks
refusing a parsed value) with :meth:`NumericField.set_invalid`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import replace

from qtpy.QtCore import QLocale, Qt, Signal
from qtpy.QtGui import QKeyEvent
from qtpy.QtWidgets import QLineEdit, QWidget

from lfm_studio.widgets.numeric_text import NumberRule, format_number, parse_number

INVALID_STYLE = "QLineEdit { border: 2px solid #d32f2f; border-radius: 3px; }"
MIN_WIDTH = 72  # pixels: the panel stays narrow; the text scrolls


class NumericField(QLineEdit):
    """A number (float, or int for integer rules) typed with its unit.

    Parameters
    ----------
    rule : what the field accepts (name, range, unit, integer, special text).
    value : the initial value in force (default: the rule's minimum).
    step : added or removed by Up/Down (0: no stepping).
    log_step : Up/Down multiply or divide by 10 instead (photon budgets).
    tip : the tooltip while the field is valid.

    Signals
    -------
    committed(value) : a valid value was committed that differs from the one in force, or that
        replaces a refused text.
    refused(reason) : the committed text was refused; the value in force is unchanged.
    """

    committed = Signal(object)
    refused = Signal(str)

    def __init__(
        self,
        rule: NumberRule,
        value: float | None = None,
        *,
        step: float = 0.0,
        log_step: bool = False,
        tip: str = "",
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self.rule, self.step, self.log_step, self.tip = rule, float(step), log_step, tip
        self._value: float | int = self._checked(rule.minimum if value is None else value)
        self._error: str | None = None  # the field's own: the typed text is not a valid number
        self._external: str | None = None  # the host's: a valid number the design refused
        self.setMinimumWidth(MIN_WIDTH)
        self.setAccessibleName(rule.name)
        self.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        self._show(self._value)
        self._restyle()  # the tooltip is ``tip`` from the start, not only after the first commit
        self.editingFinished.connect(self.commit)

    # ----- the value -----

    def value(self) -> float | int:
        """The value in force (the last valid one committed or set)."""
        return self._value

    def setValue(self, value: float | int) -> None:
        """Show ``value`` as the value in force (state -> view); emits nothing.

        A refused text waiting to be corrected stays when ``value`` is the one already in
        force (another field changed); a different value replaces it (the document changed).
        """
        value = self._checked(value)
        if self._error is not None and value == self._value:
            return
        self._value = value
        self._error = None
        self._show(value)
        self._restyle()

    def discard_edit(self) -> None:
        """Drop a refused text: show the value in force again and clear the field's own error."""
        self._error = None
        self._show(self._value)
        self._restyle()

    def error(self) -> str | None:
        """Why the committed text was refused (None: the text shows the value in force)."""
        return self._error

    def reason(self) -> str | None:
        """What the red border means: the field's own error, else the host's (None: valid)."""
        return self._error or self._external

    def set_invalid(self, message: str | None) -> None:
        """Mark the field invalid for the host's ``message`` (None: the host has no objection)."""
        self._external = message
        self._restyle()

    def suffix(self) -> str:
        """The unit as shown after the number (``" mm"``; "" without a unit)."""
        return f" {self.rule.unit}" if self.rule.unit else ""

    # ----- commit -----

    def commit(self) -> bool:
        """Parse the text; True when a valid value is in force afterwards (changed or not)."""
        text = self.text()
        if self._error is None and text == self._shown:
            return True  # nothing typed since the value was shown
        rule = self.rule if self.rule.example is not None else replace(self.rule, example=self._value)
        try:
            value = parse_number(text, rule)  # a refusal's "Fix: ... e.g." offers the value in force
        except ValueError as exc:
            self._error = str(exc)
            self._restyle()
            self.refused.emit(self._error)
            return False
        changed = value != self._value or self._error is not None  # a corrected text counts
        self._value, self._error = value, None
        self._show(value)
        self._restyle()
        if changed:
            self.committed.emit(value)
        return True

    def stepBy(self, steps: int) -> None:
        """Step the value in force (not a refused text) by ``steps`` steps, within the range; commits."""
        if not (self.step or self.log_step) or not self.isEnabled() or self.isReadOnly():
            return
        rule, base = self.rule, self._value
        if self.log_step:
            exponent = round(math.log10(base)) if base > 0 else 0
            target = 10.0 ** (exponent + steps)
        else:
            target = base + steps * self.step
        target = min(max(target, rule.minimum), rule.maximum)
        if rule.integer:
            target = round(target)
        self.setText(self._format(target))
        self._error = None
        self.commit()

    def keyPressEvent(self, event: QKeyEvent) -> None:
        steps = {
            Qt.Key.Key_Up: 1,
            Qt.Key.Key_Down: -1,
            Qt.Key.Key_PageUp: 10,
            Qt.Key.Key_PageDown: -10,
        }.get(Qt.Key(event.key()))
        if steps is None:
            super().keyPressEvent(event)
        else:
            self.stepBy(steps)

    # ----- display -----

    def _checked(self, value: float | int) -> float | int:
        number = float(value)
        if not math.isfinite(number):
            raise ValueError(f"{self.rule.name}: a value in force must be finite; got {value!r}.")
        return round(number) if self.rule.integer else number

    def _format(self, value: float | int) -> str:
        if self.rule.special_text and value <= self.rule.minimum:
            return self.rule.special_text
        return format_number(value, QLocale().decimalPoint()) + self.suffix()

    def _show(self, value: float | int) -> None:
        self._shown = self._format(value)
        self.setText(self._shown)
        self.setCursorPosition(0)

    def _restyle(self) -> None:
        reason = self.reason()
        self.setStyleSheet("" if reason is None else INVALID_STYLE)
        self.setToolTip(self.tip if reason is None else reason)
        self.setProperty("invalid", reason is not None)


def commit_all(fields: Iterable[NumericField]) -> bool:
    """Commit what is typed in the enabled ``fields`` (every one, so each shows its reason); True if all hold numbers.

    For buttons that act on the fields (Apply, Simulate): a text still being typed counts,
    and a refused one stops the action instead of running it with the value before.
    """
    return all([field.commit() for field in fields if field.isEnabled()])
