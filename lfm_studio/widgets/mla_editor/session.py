"""An editing session of the MLA editor, Qt-free: history, selection, symmetry, snapping, drags, refusals.

The widget forwards every user gesture here and, when a method returns True (a
change was committed), emits ``lensletsCommitted``. Bad values never raise: the
method returns False and :attr:`EditSession.last_error` says why.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from lfm_studio.widgets.mla_editor import model as model
from lfm_studio.widgets.mla_editor.checks import summary
from lfm_studio.widgets.mla_editor.placement import free_spot
from lfm_studio.widgets.mla_editor.presets import PresetParams, build_preset
from lfm_studio.widgets.mla_editor.symmetry import Symmetry
from lfm_studio.widgets.numeric_text import shown_units_in


@dataclass
class Drag:
    """A drag in progress: ``mode`` "move" or "resize", grabbed at lenslet ``index`` at ``start`` um."""

    mode: str
    index: int
    start: tuple[float, float]
    base: model.Lenslets
    indices: list[int]
    last: model.Lenslets


class EditSession:
    """Everything the MLA editor remembers between gestures.

    Attributes
    ----------
    symmetry : Symmetry kept by edits.
    snap_pitch_um : grid pitch for moves and adds, micrometres (None: no snapping).
    new_diameter_um, new_focal_length_mm : size of lenslets added next ("last used").
    last_error : why the last edit was refused ("" after a successful one).
    """

    def __init__(self, lenslets: Iterable[object] = ()) -> None:
        self.history = model.EditHistory(model.as_lenslets(lenslets))
        self.selected: list[int] = []
        self.symmetry = Symmetry()
        self.snap_pitch_um: float | None = None
        self.drag: Drag | None = None
        self.last_error = ""
        self.new_diameter_um, self.new_focal_length_mm = 150.0, 3.0
        self._size_new_from_layout()

    @property
    def lenslets(self) -> model.Lenslets:
        """The committed layout."""
        return self.history.current

    @property
    def shown(self) -> model.Lenslets:
        """What to draw: the drag preview while dragging, else the committed layout."""
        return self.drag.last if self.drag is not None else self.history.current

    def partners(self) -> list[int]:
        """The selection and its symmetric partners."""
        return model.with_partners(self.shown, self.selected, self.symmetry) if self.selected else []

    def select(self, indices: Iterable[int]) -> None:
        """Select ``indices`` (out-of-range ones are dropped); a single selection sets the size of new lenslets."""
        n = len(self.shown)
        self.selected = sorted({int(i) for i in indices if 0 <= int(i) < n})
        if self.selected:
            self._size_new_from_layout()

    def _size_new_from_layout(self) -> None:
        """New lenslets take the size of the first selected lenslet, else of the layout's last one
        (no lenslets: the size stays)."""
        shown = self.shown
        lens = shown[self.selected[0]] if self.selected else (shown[-1] if shown else None)
        if lens is not None:
            self.new_diameter_um, self.new_focal_length_mm = lens.aperture_diameter_um, lens.focal_length_mm

    def commit(self, lenslets: model.Lenslets, label: str, selection: Sequence[int] | None = None) -> bool:
        """Make ``lenslets`` current (one undo step); True if the layout changed."""
        self.drag = None
        changed = self.history.push(lenslets, label)
        if selection is not None:
            self.selected = list(selection)
        self.selected = [i for i in self.selected if i < len(self.lenslets)]
        self.last_error = ""
        return changed

    def refuse(self, message: str) -> bool:
        """Record why an edit was refused (the engine's "um" written "µm"); always False (nothing committed)."""
        self.last_error = shown_units_in(message)
        return False

    def replace(self, lenslets: Iterable[object], *, reset_history: bool = False) -> None:
        """Take ``lenslets`` from outside (undoable unless ``reset_history``); any drag is dropped."""
        new = model.as_lenslets(lenslets)
        self.drag = None
        if reset_history:
            self.history.reset(new)
        else:
            self.history.push(new, "external change")
        self.selected = [i for i in self.selected if i < len(new)]
        self.last_error = ""
        self._size_new_from_layout()  # another design's lenslets: its size, not the previous design's

    def undo(self) -> bool:
        """Step back; True if something was undone."""
        self.drag = None
        return self._restored(self.history.undo())

    def redo(self) -> bool:
        """Step forward; True if something was redone."""
        self.drag = None
        return self._restored(self.history.redo())

    def _restored(self, lenslets: model.Lenslets | None) -> bool:
        if lenslets is None:
            return False
        self.selected = [i for i in self.selected if i < len(lenslets)]
        self.last_error = ""
        return True

    # ----- edits -----

    def add(self, x_um: float, y_um: float) -> list[int]:
        """Add a lenslet (and its partners) at ``(x, y)`` um, snapped; the new indices (selected), [] if refused."""
        p = (x_um, y_um)
        shape = self._new_shape()
        try:
            if self.snap_pitch_um is not None:
                p = model.snap(p, self.snap_pitch_um)
            new, added = model.add(
                self.lenslets,
                p,
                diameter_um=self.new_diameter_um,
                focal_length_mm=self.new_focal_length_mm,
                shape=shape,
                symmetry=self.symmetry,
            )
        except ValueError as exc:
            self.refuse(f"add: {exc}")
            return []
        self.commit(new, "add", selection=added)
        return added

    def add_free(self, near_um: tuple[float, float], *, pupil_radius_um: float | None) -> list[int]:
        """Add a lenslet at the free spot nearest ``near_um`` (see :func:`~.placement.free_spot`); [] if refused."""
        spot = free_spot(
            self.lenslets, diameter_um=self.new_diameter_um, focal_length_mm=self.new_focal_length_mm,
            shape=self._new_shape(), near=near_um, pupil_radius_um=pupil_radius_um, symmetry=self.symmetry,
            snap_pitch_um=self.snap_pitch_um,
        )  # fmt: skip
        if spot is None:
            where = "inside the pupil" if pupil_radius_um is not None else "near the view centre"
            self.refuse(
                f"add: no free spot {where} for a {self.new_diameter_um:g} µm lenslet. "
                "Fix: delete or shrink lenslets, or double-click where the new one goes."
            )
            return []
        return self.add(*spot)

    def _new_shape(self) -> str:
        """The shape of new lenslets: the selected lenslet's, else the last lenslet's (circle in an empty layout)."""
        if self.selected:
            return self.lenslets[self.selected[-1]].shape
        return self.lenslets[-1].shape if self.lenslets else "circle"

    def delete_selected(self) -> bool:
        """Delete the selection and its partners."""
        if not self.selected:
            return False
        return self.commit(model.delete(self.lenslets, self.selected, symmetry=self.symmetry), "delete", [])

    def set_selected(self, field: model.Field, value: float) -> bool:
        """Set ``field`` of the selection (and partners); without a selection, the size of new lenslets."""
        try:
            if not self.selected:
                model.lenslet((0.0, 0.0), *self._new_size(field, value))  # validate only
            new = model.set_value(self.lenslets, self.selected, field, value, symmetry=self.symmetry)
        except ValueError as exc:
            return self.refuse(str(exc))
        if field == "diameter_um":
            self.new_diameter_um = value
        elif field == "focal_length_mm":
            self.new_focal_length_mm = value
        return self.commit(new, f"set {field}")

    def _new_size(self, field: str, value: float) -> tuple[float, float]:
        d = value if field == "diameter_um" else self.new_diameter_um
        f = value if field == "focal_length_mm" else self.new_focal_length_mm
        return d, f

    def edit_cell(self, row: int, field: model.Field, text: str) -> bool:
        """A table edit of lenslet ``row``; refused with the reason if ``text`` is not a valid value."""
        try:
            if not 0 <= row < len(self.lenslets):
                raise ValueError(f"there is no lenslet {row} (the layout has {len(self.lenslets)}).")
            value = model.parse_value(field, text)
            new = model.set_value(self.lenslets, [row], field, value, symmetry=self.symmetry)
        except ValueError as exc:
            return self.refuse(f"lenslet {row} {field}: {exc}")
        return self.commit(new, f"edit {field}")

    def apply_preset(self, kind: str, params: PresetParams, *, pupil_radius_um: float | None) -> bool:
        """Replace the layout by preset ``kind`` (kept inside the pupil if its radius is known)."""
        try:
            new = build_preset(kind, params, pupil_radius_um=pupil_radius_um)  # type: ignore[arg-type]
        except ValueError as exc:
            return self.refuse(f"preset: {exc}")
        return self.commit(new, f"{kind} preset", selection=[])

    # ----- drags -----

    def begin_drag(self, index: int, mode: str, x_um: float, y_um: float) -> None:
        """Grab lenslet ``index`` at ``(x, y)`` um to "move" or "resize" the selection (it joins it if needed)."""
        if index not in self.selected:
            self.select([index])
        base = self.lenslets
        self.drag = Drag(mode, index, (x_um, y_um), base, list(self.selected), base)

    def drag_to(self, x_um: float, y_um: float) -> model.Lenslets | None:
        """The preview with the pointer at ``(x, y)`` um, or None if it did not change (or is invalid)."""
        d = self.drag
        if d is None:
            return None
        new = self._dragged(d, x_um, y_um)
        if new is None or new == d.last:
            return None
        d.last = new
        return new

    def end_drag(self, x_um: float, y_um: float) -> bool:
        """Commit the drag ending at ``(x, y)`` um; True if the layout changed."""
        d = self.drag
        if d is None:
            return False
        new = self._dragged(d, x_um, y_um)
        return self.commit(new if new is not None else d.last, d.mode)

    def cancel_drag(self) -> bool:
        """Drop the drag in progress; True if there was one."""
        had = self.drag is not None
        self.drag = None
        return had

    def _dragged(self, d: Drag, x: float, y: float) -> model.Lenslets | None:
        try:
            if d.mode == "resize":
                lens = d.base[d.index]
                dx, dy = x - lens.center_um[0], y - lens.center_um[1]
                size = 2.0 * (max(abs(dx), abs(dy)) if lens.shape == "square" else math.hypot(dx, dy))
                return model.set_value(d.base, d.indices, "diameter_um", size, symmetry=self.symmetry)
            delta = (x - d.start[0], y - d.start[1])
            return model.move(
                d.base,
                d.indices,
                delta,
                symmetry=self.symmetry,
                anchor=d.index,
                snap_pitch_um=self.snap_pitch_um,
            )
        except ValueError:
            return None  # e.g. a zero diameter while resizing: keep the last valid frame


def status_line(
    lenslets: model.Lenslets,
    *,
    selected: int,
    issues: dict[int, list[str]],
    last_error: str,
    pupil_known: bool,
    sensor_known: bool,
) -> tuple[str, str]:
    """The editor's status line and its level ("error", "warning" or "ok")."""
    focals = sorted({lens.focal_length_mm for lens in lenslets})
    head = f"{len(lenslets)} lenslets, focal lengths {', '.join(f'{f:g}' for f in focals)} mm"
    if not lenslets:
        head = "no lenslets: an MLA needs at least one (add one, or apply a preset)"
    if selected:
        head += f"; {selected} selected"
    if last_error:
        return f"Refused: {last_error}", "error"
    if not lenslets:  # nothing to check: no "OK" under the design's refusal
        return head, "error"
    if issues:
        return f"{head}. Problems: {summary(issues)}", "warning"
    checked = ["no overlapping lenslets"]
    if pupil_known:
        checked.append("all inside the pupil")
    if sensor_known:
        checked.append("sub-images apart and on the sensor")
    return f"{head}. OK: {', '.join(checked)}.", "ok"
