"""The parameter panel: the design's optics, camera, depths and computation settings.

state -> view: the fields show the design in force, the refused values with their
reason (red border, tooltip and a line under the field) and the design warnings.
view -> state: text that is not a number in range is refused by the field itself and
recorded as the field's error (nothing else changes); a committed value builds a new design with
:func:`~lfm_studio.ui.edits.try_changes` (``Design.updated``), together with the other
values still waiting; valid -> it is put in force, invalid -> the reason is recorded
for that field and the last valid design stays in force.
"""

from __future__ import annotations

from typing import Any

import torch
from qtpy.QtWidgets import (
    QComboBox,
    QFormLayout,
    QGroupBox,
    QLabel,
    QScrollArea,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.design import ACCURACY_PRESETS, AccuracySpec, Design, describe_preset
from lfm_studio.engine.systems.kinds import kind_of
from lfm_studio.ui.edits import read_path, read_path_or_none, try_changes
from lfm_studio.ui.parameter_fields import FIELDS, ErrorLabel, FieldSpec, QuantityInput
from lfm_studio.ui.state import StudioState


class ParameterPanel(QScrollArea):
    """Editable design parameters, bound to ``state``."""

    def __init__(self, state: StudioState, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.state = state
        self.setWidgetResizable(True)
        body = QWidget(self)
        layout = QVBoxLayout(body)
        self.kind_label = QLabel(body)
        self.kind_label.setWordWrap(True)
        layout.addWidget(self.kind_label)
        self.inputs: dict[str, QuantityInput] = {}
        self.error_labels: dict[str, ErrorLabel] = {}
        self.groups: dict[str, QGroupBox] = {}
        for spec in FIELDS:
            self._add_field(spec, layout, body)
        self._add_computation(layout, body)
        self.warning_label = QLabel(body)
        self.warning_label.setWordWrap(True)
        self.warning_label.setStyleSheet("color: #8a6d00; background: #fff8e1; padding: 4px;")
        layout.addWidget(self.warning_label)
        layout.addStretch(1)
        self.setWidget(body)
        self._fit_width()

        state.design_changed.connect(self._on_design)
        state.errors_changed.connect(self._on_errors)
        state.warnings_changed.connect(self._on_warnings)
        state.device_changed.connect(self._on_device)
        self._on_design(state.design)
        self._on_errors(state.errors)
        self._on_warnings(state.warnings)

    def disconnect_state(self) -> None:
        """Stop observing the state (before the panel is destroyed)."""
        state = self.state
        state.design_changed.disconnect(self._on_design)
        state.errors_changed.disconnect(self._on_errors)
        state.warnings_changed.disconnect(self._on_warnings)
        state.device_changed.disconnect(self._on_device)

    # ----- building -----

    def _group(self, name: str, layout: QVBoxLayout, body: QWidget) -> QFormLayout:
        box = self.groups.get(name)
        if box is None:
            box = QGroupBox(name, body)
            QFormLayout(box)
            layout.addWidget(box)
            self.groups[name] = box
        return box.layout()

    def _add_field(self, spec: FieldSpec, layout: QVBoxLayout, body: QWidget) -> None:
        form = self._group(spec.group, layout, body)
        field = QuantityInput(spec, body)
        field.edited.connect(self._on_edited)
        field.refused.connect(self.state.set_field_error)
        error = ErrorLabel(body)
        form.addRow(spec.label, field)
        form.addRow(error)
        self.inputs[spec.path] = field
        self.error_labels[spec.path] = error

    def _add_computation(self, layout: QVBoxLayout, body: QWidget) -> None:
        form = self._group("Computation", layout, body)
        self.accuracy = QComboBox(body)
        self.accuracy.addItems(list(ACCURACY_PRESETS))
        self.accuracy.setToolTip("\n".join(describe_preset(name) for name in ACCURACY_PRESETS))
        self.accuracy.textActivated.connect(self._on_accuracy)
        form.addRow("Accuracy preset", self.accuracy)
        self.device = QComboBox(body)
        self.device.addItem("cpu")
        self.device.addItem("cuda")
        if not torch.cuda.is_available():
            item = self.device.model().item(1)
            item.setEnabled(False)
            item.setToolTip("No CUDA device is available here.")
        self.device.textActivated.connect(self.state.set_device)
        form.addRow("Device", self.device)

    # ----- state -> view -----

    def _fit_width(self) -> None:
        """At least as wide as the fields need beside the vertical scroll bar, so the panel never
        scrolls sideways (a fixed 340 px left the conventional preset's fields 1 px too wide)."""
        needed = self.widget().minimumSizeHint().width() + self.verticalScrollBar().sizeHint().width()
        self.setMinimumWidth(max(340, needed + 2 * self.frameWidth()))

    def _on_design(self, design: Design) -> None:
        kind = kind_of(design)
        self.kind_label.setText(f"<b>{design.name}</b><br>{kind.label}")
        pending = self.state.errors
        for path, field in self.inputs.items():
            applies = kind in field.spec.kinds
            field.setEnabled(applies)
            if not applies:
                # greyed: this design's own value ("none" / 0 where it has none), not the last design's
                field.discard_edits()
                field.set_value(read_path_or_none(design, path))
            elif path not in pending:
                field.set_value(read_path(design, path))
        preset = design.accuracy.preset if design.accuracy.matches_preset() else "custom"
        if self.accuracy.findText(preset) < 0:
            self.accuracy.addItem(preset)
        self.accuracy.setCurrentText(preset)
        self._fit_width()

    def _on_errors(self, errors: dict[str, str]) -> None:
        design = self.state.design
        for path, field in self.inputs.items():
            message = errors.get(path)
            was_invalid = bool(field.property("invalid"))
            field.set_invalid(message)
            self.error_labels[path].show_error(message)
            if was_invalid and message is None and kind_of(design) in field.spec.kinds:
                field.discard_edits()  # the refused value is dropped
                field.set_value(read_path(design, path))

    def _on_warnings(self, warnings: tuple[str, ...]) -> None:
        self.warning_label.setText("\n\n".join(f"⚠ {w}" for w in warnings))
        self.warning_label.setVisible(bool(warnings))

    def _on_device(self, device: str) -> None:
        self.device.setCurrentText(device)

    # ----- view -> state -----

    def _on_edited(self, path: str) -> None:
        value = self.inputs[path].value()
        waiting = {
            p: self.inputs[p].value()
            for p in self.state.errors
            if p in self.inputs and p != path and self.inputs[p].error() is None  # not text that is no number
        }
        self._commit({**waiting, path: value}, path, fallback={path: value} if waiting else None)

    def _on_accuracy(self, name: str) -> None:
        if name in ACCURACY_PRESETS:
            self._commit({"accuracy": AccuracySpec.from_preset(name)}, "accuracy")

    def _commit(self, changes: dict[str, Any], path: str, fallback: dict[str, Any] | None = None) -> None:
        """Apply ``changes`` together; if refused, try ``fallback`` (the edit alone) before refusing.

        A refusal records the edit's own reason: with a fallback, the reason the edit alone was
        refused (the combined outcome's reason also names the other waiting fields).
        """
        state = self.state
        outcome = try_changes(state.design, changes)
        accepted = changes
        if not outcome.ok and fallback is not None:
            outcome, accepted = try_changes(state.design, fallback), fallback
        if outcome.ok:
            state.set_design(outcome.design, warnings=outcome.warnings)
            state.clear_errors(accepted)
        else:
            state.set_field_error(path, outcome.error)
