"""The MLA editor's control rows: presets, edit actions with the selection's size, snapping and symmetry.

Each row only emits what the user asked for; the editor acts on it. Values are
set back with signals blocked (``set_*`` methods), so state -> view never echoes.
Numbers are typed into :class:`~lfm_studio.widgets.numeric_field.NumericField` (one
policy for the whole studio); a refused number is reported by the field's ``refused``
signal, which the editor shows in its status line.
"""

from __future__ import annotations

from qtpy.QtCore import Signal
from qtpy.QtWidgets import QCheckBox, QComboBox, QHBoxLayout, QLabel, QPushButton, QToolButton, QWidget

from lfm_studio.widgets.mla_editor.model import LENSLET_RULES
from lfm_studio.widgets.mla_editor.presets import (
    COUNT_MEANING,
    CUSTOM,
    CUSTOM_LABEL,
    DEFAULT_COUNTS,
    PRESET_LABELS,
    SHAPE_LABELS,
    PresetParams,
)
from lfm_studio.widgets.mla_editor.symmetry import MAX_ROTATION, Symmetry
from lfm_studio.widgets.numeric_field import NumericField, commit_all
from lfm_studio.widgets.numeric_text import NumberRule

MAX_COUNT = 500  # preset size: lenslets per side, rings or lenslets


def number(name: str, unit: str, *, minimum: float, maximum: float, value: float, step: float = 0.0,
           integer: bool = False, special_text: str = "") -> NumericField:  # fmt: skip
    """A numeric field showing its unit, that reports only finished edits (Enter, arrows, focus out)."""
    rule = NumberRule(name, minimum, maximum, unit, integer=integer, special_text=special_text, example=value)
    field = NumericField(rule, value, step=step)
    field.setMaximumWidth(120)
    return field


def _row(parent: QWidget, *widgets: QWidget | str) -> QHBoxLayout:
    layout = QHBoxLayout(parent)
    layout.setContentsMargins(0, 0, 0, 0)
    for w in widgets:
        layout.addWidget(QLabel(w) if isinstance(w, str) else w)
    layout.addStretch(1)
    return layout


class PresetBar(QWidget):
    """Preset kind and parameters; ``applyRequested(kind, PresetParams)`` on Apply."""

    applyRequested = Signal(str, object)  # noqa: N815 - Qt signal names are camelCase

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.kind = QComboBox()
        self.kind.addItem(CUSTOM_LABEL, CUSTOM)  # the layout shown matches no preset
        for key, label in PRESET_LABELS.items():
            self.kind.addItem(label, key)
        self.kind.setCurrentIndex(self.kind.findData("xlfm"))
        defaults = PresetParams()
        self.pitch = number(
            "preset pitch", "µm", minimum=0.001, maximum=1e6, value=defaults.pitch_um, step=10
        )
        self.count = number("preset n", "", minimum=0, maximum=MAX_COUNT, value=DEFAULT_COUNTS["xlfm"], step=1,
                            integer=True)  # fmt: skip
        self.focal_a = number("preset f", "mm", minimum=0.001, maximum=1e5, value=defaults.focal_lengths_mm[0],
                              step=0.5)  # fmt: skip
        self.focal_b = number("preset second f", "mm", minimum=0.001, maximum=1e5,
                              value=defaults.focal_lengths_mm[1], step=0.5)  # fmt: skip
        self.diameter = number("preset Ø", "µm", minimum=0.001, maximum=1e6, value=defaults.aperture_diameter_um,
                               step=10)  # fmt: skip
        self.shape = QComboBox()  # the apertures the preset builds
        for key, label in SHAPE_LABELS.items():
            self.shape.addItem(label, key)
        self.shape.setToolTip("aperture shape of the preset's lenslets (Ø: a square's side)")
        self.apply = QPushButton("Apply preset")
        self.apply.setToolTip("Replace all lenslets by this preset (undo with Ctrl+Z)")
        self._counts = dict(DEFAULT_COUNTS)
        _row(
            self, "Preset", self.kind, "pitch", self.pitch, "n", self.count, "f",
            self.focal_a, self.focal_b, "Ø", self.diameter, self.shape, self.apply,
        )  # fmt: skip
        self.kind.currentIndexChanged.connect(self._on_kind)
        self.count.committed.connect(self._remember_count)
        self.apply.clicked.connect(self._on_apply)
        self._on_kind()

    def current_kind(self) -> str:
        """The chosen preset: "square", "hex" or "xlfm" ("custom": the layout matches none)."""
        return str(self.kind.currentData())

    def params(self) -> PresetParams:
        """The parameters as entered."""
        focals = (self.focal_a.value(), self.focal_b.value())
        return PresetParams(
            pitch_um=self.pitch.value(),
            count=self.count.value(),
            focal_lengths_mm=focals if self.current_kind() == "xlfm" else focals[:1],
            aperture_diameter_um=self.diameter.value(),
            lenslet_shape=self.shape.currentData(),
        )

    def set_params(self, params: PresetParams) -> None:
        """Show ``params`` (pitch, focal lengths, aperture and its shape; the count stays per kind)."""
        self.shape.setCurrentIndex(self.shape.findData(params.lenslet_shape))
        self.pitch.setValue(params.pitch_um)
        self.focal_a.setValue(params.focal_lengths_mm[0])
        self.focal_b.setValue(params.focal_lengths_mm[-1])
        self.diameter.setValue(params.aperture_diameter_um)

    def show_kind(self, kind: str, count: int = 0) -> None:
        """Show preset ``kind`` (``CUSTOM`` for a layout no preset rebuilds) with ``count``, emitting nothing."""
        if kind != CUSTOM and count:
            self._counts[kind] = count
        self.kind.blockSignals(True)
        self.kind.setCurrentIndex(self.kind.findData(kind))
        self.kind.blockSignals(False)
        self._on_kind()

    def _on_kind(self, *_args) -> None:
        kind = self.current_kind()
        custom = kind == CUSTOM
        for widget in (*self.fields(), self.shape, self.apply):
            widget.setEnabled(not custom)
        self.apply.setToolTip(
            "The layout as drawn matches no preset: pick one to replace it"
            if custom
            else "Replace all lenslets by this preset (undo with Ctrl+Z)"
        )
        if custom:
            return
        self.count.blockSignals(True)
        self.count.setValue(self._counts[kind])
        self.count.blockSignals(False)
        self.count.setToolTip(f"n: {COUNT_MEANING[kind]}")
        self.focal_b.setEnabled(kind == "xlfm")
        self.focal_b.setToolTip("focal length of the second group" if kind == "xlfm" else "xlfm preset only")

    def _remember_count(self, value: int) -> None:
        self._counts[self.current_kind()] = value

    def fields(self) -> tuple[NumericField, ...]:
        """The typed numbers of the preset."""
        return (self.pitch, self.count, self.focal_a, self.focal_b, self.diameter)

    def _on_apply(self) -> None:
        if self.current_kind() != CUSTOM and commit_all(
            self.fields()
        ):  # a refused number is not replaced by the one before it
            self.applyRequested.emit(self.current_kind(), self.params())


class EditBar(QWidget):
    """Add / Delete / Undo / Redo / Fit, and the diameter and focal length of the selection (or of new lenslets)."""

    addClicked = Signal()  # noqa: N815 - Qt signal names are camelCase
    deleteClicked = Signal()  # noqa: N815 - Qt signal names are camelCase
    undoClicked = Signal()  # noqa: N815 - Qt signal names are camelCase
    redoClicked = Signal()  # noqa: N815 - Qt signal names are camelCase
    fitClicked = Signal()  # noqa: N815 - Qt signal names are camelCase
    diameterEdited = Signal(object)  # noqa: N815 - Qt signal names are camelCase; a float
    focalEdited = Signal(object)  # noqa: N815 - Qt signal names are camelCase; a float

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.add, self.delete, self.undo, self.redo, self.fit = (
            QToolButton(text=t) for t in ("Add", "Delete", "Undo", "Redo", "Fit")
        )
        self.add.setToolTip(
            "Add a lenslet like the selected (or last) one at the free spot nearest the view centre, inside the"
            " pupil (or double-click the canvas where it goes)"
        )
        self.delete.setToolTip("Delete the selected lenslets (Delete)")
        self.fit.setToolTip("Show the whole pupil and every lenslet")
        self.diameter = NumericField(LENSLET_RULES["diameter_um"], 1000.0, step=10)  # the table's rules
        self.focal = NumericField(LENSLET_RULES["focal_length_mm"], 26.0, step=0.5)
        for box, what in ((self.diameter, "aperture diameter"), (self.focal, "focal length")):
            box.tip = f"{what} of the selected lenslets, and of lenslets you add"
            box.setToolTip(box.tip)
        _row(
            self, self.add, self.delete, self.undo, self.redo, self.fit, "  Ø", self.diameter, "f", self.focal
        )
        self.add.clicked.connect(self.addClicked)
        self.delete.clicked.connect(self.deleteClicked)
        self.undo.clicked.connect(self.undoClicked)
        self.redo.clicked.connect(self.redoClicked)
        self.fit.clicked.connect(self.fitClicked)
        self.diameter.committed.connect(self.diameterEdited)
        self.focal.committed.connect(self.focalEdited)

    def set_values(self, diameter_um: float, focal_length_mm: float) -> None:
        """Show a diameter and focal length without emitting edits."""
        for box, value in ((self.diameter, diameter_um), (self.focal, focal_length_mm)):
            box.blockSignals(True)
            box.setValue(value)
            box.blockSignals(False)

    def set_states(self, *, undo: str | None, redo: str | None, has_selection: bool) -> None:
        """Enable Undo/Redo (tooltips name the step; None: nothing to undo/redo) and Delete."""
        self.undo.setEnabled(undo is not None)
        self.redo.setEnabled(redo is not None)
        self.undo.setToolTip(f"Undo {undo} (Ctrl+Z)" if undo else "Nothing to undo")
        self.redo.setToolTip(f"Redo {redo} (Ctrl+Shift+Z)" if redo else "Nothing to redo")
        self.delete.setEnabled(has_selection)


class SymmetryBar(QWidget):
    """Snap-to-grid pitch and the symmetry that edits keep; ``changed()`` on any change."""

    changed = Signal()

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.snap = QCheckBox("Snap to grid")
        self.pitch = number("snap pitch", "µm", minimum=0.001, maximum=1e6, value=100.0, step=10)
        self.mirror_x = QCheckBox("Mirror x")
        self.mirror_x.setToolTip(
            "Keep mirror symmetry (x, y) -> (-x, y): edits apply to the mirrored partner"
        )
        self.mirror_y = QCheckBox("Mirror y")
        self.mirror_y.setToolTip(
            "Keep mirror symmetry (x, y) -> (x, -y): edits apply to the mirrored partner"
        )
        self.rotation = number("rotation", "fold", minimum=1, maximum=MAX_ROTATION, value=1, step=1, integer=True,
                               special_text="off")  # fmt: skip
        self.rotation.tip = "Keep n-fold rotational symmetry about the optical axis (1 or off: none)"
        self.rotation.setToolTip(self.rotation.tip)
        _row(
            self,
            self.snap,
            self.pitch,
            "  Symmetry:",
            self.mirror_x,
            self.mirror_y,
            "rotation",
            self.rotation,
        )
        for box in (self.snap, self.mirror_x, self.mirror_y):
            box.toggled.connect(self.changed)
        self.pitch.committed.connect(self.changed)
        self.rotation.committed.connect(self.changed)

    def symmetry(self) -> Symmetry:
        """The symmetry edits keep."""
        return Symmetry(self.mirror_x.isChecked(), self.mirror_y.isChecked(), self.rotation.value())

    def snap_pitch(self) -> float | None:
        """Grid pitch in um, or None when snapping is off."""
        return self.pitch.value() if self.snap.isChecked() else None

    def set_symmetry(self, symmetry: Symmetry) -> None:
        """Show ``symmetry`` (emits ``changed`` once if it differs)."""
        self._quietly(
            lambda: (
                self.mirror_x.setChecked(symmetry.mirror_x),
                self.mirror_y.setChecked(symmetry.mirror_y),
                self.rotation.setValue(symmetry.rotation),
            )
        )

    def set_snap(self, pitch_um: float | None) -> None:
        """Turn snapping on with ``pitch_um`` (None: off)."""
        self._quietly(
            lambda: (
                self.snap.setChecked(pitch_um is not None),
                self.pitch.setValue(pitch_um) if pitch_um is not None else None,
            )
        )

    def _quietly(self, change) -> None:
        widgets = (self.snap, self.pitch, self.mirror_x, self.mirror_y, self.rotation)
        for w in widgets:
            w.blockSignals(True)
        try:
            change()
        finally:
            for w in widgets:
                w.blockSignals(False)
        self.changed.emit()
