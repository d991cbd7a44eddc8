"""The MLA layout editor: a reusable widget (also inside napari) to design a microlens array visually.

:class:`MLAEditor` shows the MLA plane over the pupil footprint (canvas), where each
lenslet's sub-image lands on the sensor (sensor view) and a table of lenslets, with
preset, edit, snap and symmetry controls. Gestures go to a Qt-free
:class:`~lfm_studio.widgets.mla_editor.session.EditSession` (pure edits, undo/redo
snapshots, refusals with reasons); the widget draws the result and emits
``lensletsCommitted(tuple)`` only when an edit is committed (drag end, add, delete,
resize, table edit, preset, undo/redo) and ``lensletsPreview(tuple)`` while
dragging. Keys: Ctrl+Z undo, Ctrl+Shift+Z / Ctrl+Y redo, Delete remove the
selection, Ctrl+A select all, Escape cancel a drag or clear the selection.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from qtpy.QtCore import Signal
from qtpy.QtWidgets import QWidget

from lfm_studio.engine.design import LensletSpec
from lfm_studio.widgets.mla_editor import model as model
from lfm_studio.widgets.mla_editor.keys import EditorKeys
from lfm_studio.widgets.mla_editor.presets import PresetParams, estimate_params, matching_preset
from lfm_studio.widgets.mla_editor.session import EditSession
from lfm_studio.widgets.mla_editor.symmetry import Symmetry
from lfm_studio.widgets.mla_editor.views import EditorViews

__all__ = ["MLAEditor"]


class MLAEditor(QWidget):
    """Edit a microlens-array layout (lenslet centres, diameters and focal lengths).

    Parameters
    ----------
    lenslets : sequence of LensletSpec (or dicts as in a design file)
        The layout to edit; MLA-plane micrometres, x right, y up.
    pupil_radius_um : float, optional
        Radius of the pupil footprint at the MLA (Fourier LFM), micrometres.
    sensor_size_um : (width, height), optional
        Sensor size in micrometres (see :meth:`set_sensor` for the sub-images).
    """

    lensletsCommitted = Signal(object)  # noqa: N815 - Qt signal names are camelCase
    lensletsPreview = Signal(object)  # noqa: N815
    selectionChanged = Signal(object)  # noqa: N815

    def __init__(
        self,
        lenslets: Sequence[LensletSpec] | tuple = (),
        *,
        pupil_radius_um: float | None = None,
        sensor_size_um: tuple[float, float] | None = None,
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self._session = EditSession(lenslets)
        self._views = v = EditorViews(self)
        self.presets, self.edits, self.symmetry_bar, self.status = (
            v.presets,
            v.edits,
            v.symmetry_bar,
            v.status,
        )
        self.canvas, self.sensor_view, self.table_model, self.table = (
            v.canvas,
            v.sensor_view,
            v.table_model,
            v.table,
        )
        v.set_pupil_radius(pupil_radius_um)
        v.sensor_size_um = (
            None if sensor_size_um is None else (float(sensor_size_um[0]), float(sensor_size_um[1]))
        )
        self._connect()
        self._show_matching_preset()
        self._refresh()
        self.fit()

    def _connect(self) -> None:
        c = self.canvas
        c.clicked.connect(self._on_click)
        c.doubleClicked.connect(self.add_lenslet)
        c.dragStarted.connect(self.begin_drag)
        c.dragMoved.connect(self.drag_to)
        c.dragFinished.connect(self.end_drag)
        c.bandSelected.connect(self._on_band)
        self.table_model.editRequested.connect(self.edit_cell)
        self.table.selectionEdited.connect(self._on_table_selection)
        self.presets.applyRequested.connect(self.apply_preset)
        e = self.edits
        e.addClicked.connect(self.add_free_lenslet)
        e.deleteClicked.connect(self.delete_selected)
        e.undoClicked.connect(self.undo)
        e.redoClicked.connect(self.redo)
        e.fitClicked.connect(self.fit)
        e.diameterEdited.connect(self.set_selected_diameter)
        e.focalEdited.connect(self.set_selected_focal_length)
        self.symmetry_bar.changed.connect(self._on_symmetry)
        self._refused_input = ""  # the last number a field refused, while the status line shows it
        for field in self.numeric_fields():
            field.refused.connect(self._on_refused)
            field.committed.connect(self._on_number_committed)
        self._keys = EditorKeys(self)
        self._keys.triggered.connect(self._on_key)
        for w in (self, self.canvas, self.sensor_view, self.table):
            w.installEventFilter(self._keys)

    # ----- the contract -----

    def lenslets(self) -> tuple[LensletSpec, ...]:
        """The committed layout (a drag in progress is not included until it ends)."""
        return self._session.lenslets

    def set_lenslets(self, lenslets: Iterable[LensletSpec], *, reset_history: bool = False) -> None:
        """Show ``lenslets`` (state -> view) without emitting signals; undoable unless ``reset_history``."""
        new = model.as_lenslets(lenslets)
        s = self._session
        if not reset_history and (new == s.lenslets or (s.drag is not None and new == s.drag.last)):
            return  # our own commit or preview coming back: keep the drag, the history and the view
        blocked = self.blockSignals(True)
        try:
            self.canvas.cancel_drag()
            s.replace(new, reset_history=reset_history)
            self._show_matching_preset()  # another design: its preset, not the last one's
            self._refresh()
        finally:
            self.blockSignals(blocked)

    def set_pupil_radius(self, radius_um: float | None) -> None:
        """Radius of the pupil footprint at the MLA in micrometres (None: unknown)."""
        if radius_um == self._views.pupil_radius_um:
            return  # the application repeats it after every edit: no redraw of a big array
        self._views.set_pupil_radius(radius_um)
        self._refresh()

    def set_sensor(
        self,
        size_um: tuple[float, float] | None,
        sub_image_radius_um: float | None,
        magnification: float | None = None,
        *,
        pixel_pitch_um: float | None = None,
    ) -> None:
        """Sensor ``(width, height)`` um and sub-image radius um (None or 0: unknown); sub-images are centred
        on ``magnification`` times the lenslet centre (default 1: Fourier and conventional LFMs). With the
        camera's ``pixel_pitch_um``, overlaps shallower than half a pixel are ignored, as in the design checks.
        The sensor view refits only when the sensor or sub-image size changes (a user's zoom survives edits)."""
        v = self._views
        size = None if size_um is None else (float(size_um[0]), float(size_um[1]))
        magnification = 1.0 if magnification is None else float(magnification)
        new = (size, sub_image_radius_um, magnification, pixel_pitch_um)
        if new == (v.sensor_size_um, v.sub_image_radius_um, v.magnification, v.pixel_pitch_um):
            return  # unchanged (repeated after every edit): no redraw
        refit = (size, sub_image_radius_um) != (v.sensor_size_um, v.sub_image_radius_um)
        v.sensor_size_um, v.sub_image_radius_um, v.magnification, v.pixel_pitch_um = new
        self._refresh()
        if refit:
            self.sensor_view.fit()

    def set_summary(self, text: str | None) -> None:
        """Show ``text`` in the status line instead of the checks of the lenslets shown: for a layout
        edited elsewhere of which the editor shows only a patch (a regular grid). The sensor view then
        claims no overlap status either. None: the checks again."""
        if text == self._views.summary:
            return
        self._views.set_summary(text, None if text is None else "a central patch of the array is drawn")
        self._refresh()

    def undo(self) -> bool:
        """Revert the last committed edit (emits ``lensletsCommitted``); True if there was one."""
        self.canvas.cancel_drag()
        return self._done(self._session.undo())

    def redo(self) -> bool:
        """Re-apply the last undone edit (emits ``lensletsCommitted``); True if there was one."""
        self.canvas.cancel_drag()
        return self._done(self._session.redo())

    def can_undo(self) -> bool:
        """True if :meth:`undo` would change something."""
        return self._session.history.can_undo()

    def can_redo(self) -> bool:
        """True if :meth:`redo` would change something."""
        return self._session.history.can_redo()

    def selected_indices(self) -> list[int]:
        """Indices of the selected lenslets, sorted."""
        return list(self._session.selected)

    # ----- more API (the controls use it; so can tests and the application) -----

    def set_selection(self, indices: Iterable[int]) -> None:
        """Select the lenslets ``indices`` (others are deselected)."""
        self._select(indices)

    def symmetry(self) -> Symmetry:
        """The symmetry edits keep."""
        return self._session.symmetry

    def set_symmetry(self, symmetry: Symmetry) -> None:
        """Keep ``symmetry`` (mirrors, n-fold rotation) in later edits."""
        self.symmetry_bar.set_symmetry(symmetry)

    def set_snap(self, pitch_um: float | None) -> None:
        """Snap moved and added lenslets to a grid of ``pitch_um`` through the axis (None: off)."""
        self.symmetry_bar.set_snap(pitch_um)

    def issues(self) -> dict[int, list[str]]:
        """Reasons per lenslet index: overlaps, outside the pupil, sub-image problems."""
        return {i: list(v) for i, v in self._views.issues.items()}

    def last_error(self) -> str:
        """Why the last refused edit was refused ("" after a successful one)."""
        return self._session.last_error

    def status_text(self) -> str:
        """The status line as plain text."""
        return self._views.status_plain

    def fit(self) -> None:
        """Show the whole pupil, sensor and every lenslet."""
        self._views.fit()

    def numeric_fields(self) -> tuple:
        """The typed numbers: preset, edit bar (Ø, f) and snap/symmetry fields."""
        bar = self.symmetry_bar
        return (*self.presets.fields(), self.edits.diameter, self.edits.focal, bar.pitch, bar.rotation)

    def add_lenslet(self, x_um: float, y_um: float) -> list[int]:
        """Add a lenslet (and its partners) at ``(x, y)`` um, snapped if snapping is on, with the last used
        diameter and focal length and the shape of the selected (or last) lenslet; returns the new indices
        (now selected)."""
        added = self._session.add(x_um, y_um)
        self._done(bool(added))
        return added

    def delete_selected(self) -> bool:
        """Delete the selected lenslets and their symmetric partners."""
        return self._done(self._session.delete_selected())

    def set_selected_diameter(self, diameter_um: float) -> bool:
        """Aperture diameter of the selection and its partners (without a selection: of new lenslets)."""
        return self._done(self._session.set_selected("diameter_um", diameter_um))

    def set_selected_focal_length(self, focal_length_mm: float) -> bool:
        """Focal length of the selection and its partners (without a selection: of new lenslets)."""
        return self._done(self._session.set_selected("focal_length_mm", focal_length_mm))

    def edit_cell(self, row: int, field: str, text: str) -> bool:
        """Table edit: ``field`` (x_um, y_um, diameter_um, focal_length_mm) of lenslet ``row`` := ``text``.

        An invalid value is refused with the reason in the status line (and :meth:`last_error`).
        """
        return self._done(self._session.edit_cell(row, field, text))  # type: ignore[arg-type]

    def apply_preset(self, kind: str, params: PresetParams | None = None) -> bool:
        """Replace the layout by preset ``kind`` ("square", "hex", "xlfm"), kept inside the pupil."""
        params = params or self.presets.params()
        changed = self._done(
            self._session.apply_preset(kind, params, pupil_radius_um=self._views.pupil_radius_um)
        )
        if changed:
            self.fit()
        return changed

    # ----- dragging (canvas gestures; callable directly) -----

    def begin_drag(self, index: int, mode: str, x_um: float, y_um: float) -> None:
        """Grab lenslet ``index`` at ``(x, y)`` um to "move" or "resize" the selection."""
        self._session.begin_drag(index, mode, x_um, y_um)
        self._select(self._session.selected)

    def drag_to(self, x_um: float, y_um: float) -> None:
        """Preview the drag with the pointer at ``(x, y)`` um (emits ``lensletsPreview``)."""
        preview = self._session.drag_to(x_um, y_um)
        if preview is not None:
            self._refresh()
            self.lensletsPreview.emit(preview)

    def end_drag(self, x_um: float, y_um: float) -> bool:
        """Finish the drag at ``(x, y)`` um: one ``lensletsCommitted`` if the layout changed."""
        return self._done(self._session.end_drag(x_um, y_um))

    def cancel_drag(self) -> None:
        """Abandon the drag in progress; listeners get a preview of the committed layout back."""
        self.canvas.cancel_drag()
        if self._session.cancel_drag():
            self._refresh()
            self.lensletsPreview.emit(self.lenslets())

    # ----- internals -----

    def _done(self, committed: bool) -> bool:
        self._refresh()
        if committed:
            self.lensletsCommitted.emit(self.lenslets())
        return committed

    def add_free_lenslet(self) -> list[int]:
        """The Add button: a lenslet like the selected (or last) one at the free spot nearest the view centre,
        inside the pupil (a free lattice site of the layout first); returns the new indices, [] if none is free."""
        (x0, x1), (y0, y1) = self.canvas.getViewBox().viewRange()
        centre = ((x0 + x1) / 2.0, (y0 + y1) / 2.0)
        added = self._session.add_free(centre, pupil_radius_um=self._views.pupil_radius_um)
        self._done(bool(added))
        return added

    def _show_matching_preset(self) -> None:
        """The preset row shows the preset that rebuilds the layout (or "custom") with its parameters."""
        lenslets = self._session.lenslets
        self.presets.set_params(estimate_params(lenslets))
        self.presets.show_kind(*matching_preset(lenslets))

    def _on_click(self, index: int, additive: bool) -> None:
        current = set(self._session.selected)
        if index < 0:
            self._select(current if additive else [])
        else:
            self._select(current ^ {index} if additive else [index])

    def _on_band(self, indices: list[int], additive: bool) -> None:
        self._select(set(indices) | (set(self._session.selected) if additive else set()))

    def _on_refused(self, reason: str) -> None:
        self._session.refuse(reason)  # the field keeps the text and its red border; the status line says why
        self._refused_input = reason
        self._views.render_selection(self._session)

    def _on_number_committed(self, _value: object) -> None:
        if self._refused_input and self._session.last_error == self._refused_input:  # corrected
            self._session.last_error = self._refused_input = ""
            self._views.render_selection(self._session)

    def _on_table_selection(self, rows: list[int]) -> None:
        self._select(rows, from_table=True)

    def _on_symmetry(self) -> None:
        self._session.symmetry = self.symmetry_bar.symmetry()
        self._session.snap_pitch_um = self.symmetry_bar.snap_pitch()
        self.canvas.set_snap_grid(self._session.snap_pitch_um)
        self._select(self._session.selected)

    def _select(self, indices: Iterable[int], *, from_table: bool = False) -> None:
        self._session.select(indices)
        self._views.render_selection(self._session, from_table=from_table)
        self.selectionChanged.emit(self.selected_indices())

    def _refresh(self) -> None:
        self._views.render(self._session)

    def _on_key(self, action: str) -> None:
        if action == "undo":
            self.undo()
        elif action == "redo":
            self.redo()
        elif action == "delete":
            self.delete_selected()
        elif action == "select_all":
            self._select(range(len(self.lenslets())))
        elif self._session.drag is not None:
            self.cancel_drag()
        else:
            self._select([])
