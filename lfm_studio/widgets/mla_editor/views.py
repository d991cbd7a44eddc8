"""The MLA editor's widgets and how an editing session is drawn on them (state -> view only).

:class:`EditorViews` lays out the control rows, the MLA canvas, the sensor view,
the lenslet table and the status line on a host widget, holds the optical context
the checks need (pupil, sensor, sub-image radius) and renders an
:class:`~lfm_studio.widgets.mla_editor.session.EditSession`. It emits nothing; the
editor wires user gestures to the session.
"""

from __future__ import annotations

from dataclasses import replace

from qtpy.QtCore import Qt
from qtpy.QtWidgets import QLabel, QSplitter, QVBoxLayout, QWidget

from lfm_studio.engine.design import LensletSpec
from lfm_studio.widgets.mla_editor.canvas import MLACanvas
from lfm_studio.widgets.mla_editor.checks import SensorLayout, mla_issues, sensor_layout
from lfm_studio.widgets.mla_editor.controls import EditBar, PresetBar, SymmetryBar
from lfm_studio.widgets.mla_editor.sensor import SensorView
from lfm_studio.widgets.mla_editor.session import EditSession, status_line
from lfm_studio.widgets.mla_editor.style import focal_colors
from lfm_studio.widgets.mla_editor.table import LensletTable, LensletTableModel

LIVE_CHECK_LIMIT = 2000  # larger arrays are checked when a drag ends, not at every preview frame
STATUS_COLORS = {
    "error": "#e53935",
    "warning": "#ef6c00",
    "ok": "#43a047",
    "info": "#607d8b",
}  # legible on light and dark


class EditorViews:
    """The editor's widgets on ``host`` and the optical context of the checks.

    Attributes
    ----------
    pupil_radius_um, sensor_size_um, sub_image_radius_um, magnification, pixel_pitch_um
        What the checks and the sensor view need (None: unknown).
    issues : reasons per lenslet index from the last render (MLA plane and sensor).
    status_plain : the status line as plain text.
    """

    def __init__(self, host: QWidget) -> None:
        self.presets, self.edits, self.symmetry_bar = PresetBar(), EditBar(), SymmetryBar()
        self.canvas, self.sensor_view = MLACanvas(), SensorView()
        self.table_model = LensletTableModel(host)
        self.table = LensletTable(self.table_model)
        self.status = QLabel()
        self.status.setWordWrap(True)
        self.status.setTextFormat(Qt.TextFormat.RichText)
        self.canvas.setMinimumSize(320, 320)
        self.sensor_view.setMinimumSize(220, 220)
        right = QSplitter(Qt.Orientation.Vertical)
        right.addWidget(self.sensor_view)
        right.addWidget(self.table)
        main = QSplitter(Qt.Orientation.Horizontal)
        main.addWidget(self.canvas)
        main.addWidget(right)
        main.setStretchFactor(0, 3)
        main.setStretchFactor(1, 2)
        layout = QVBoxLayout(host)
        for w in (self.presets, self.edits, self.symmetry_bar):
            layout.addWidget(w)
        layout.addWidget(main, 1)
        layout.addWidget(self.status)
        self.pupil_radius_um: float | None = None
        self.sensor_size_um: tuple[float, float] | None = None
        self.sub_image_radius_um: float | None = None
        self.magnification = 1.0
        self.pixel_pitch_um: float | None = None
        self.issues: dict[int, list[str]] = {}
        self.status_plain = ""
        self.summary: str | None = None  # a layout edited elsewhere: shown instead of the checks
        self._colors: dict = {}
        self._plane_issues: dict[int, list[str]] = {}
        self._sensor_layout: SensorLayout | None = None

    def set_pupil_radius(self, radius_um: float | None) -> None:
        """Pupil footprint radius at the MLA, micrometres (None: unknown)."""
        self.pupil_radius_um = radius_um
        self.canvas.set_pupil_radius(radius_um)

    def fit(self) -> None:
        """Show the whole pupil, sensor and every lenslet."""
        self.canvas.fit()
        self.sensor_view.fit()

    def render(self, s: EditSession) -> None:
        """Draw everything: lenslets, checks (live below :data:`LIVE_CHECK_LIMIT` lenslets), table, controls."""
        shown = s.shown
        self._colors = focal_colors(lens.focal_length_mm for lens in shown)
        self.canvas.show_lenslets(shown, self._colors)
        if s.drag is None or len(shown) <= LIVE_CHECK_LIMIT:
            self._plane_issues = mla_issues(shown, self.pupil_radius_um)
            self._sensor_layout = self._layout_of(shown, checks=True)
        elif self._sensor_layout is not None:  # big array mid-drag: move the discs, check on release
            old = self._sensor_layout
            moved = self._layout_of(shown, checks=False)
            self._sensor_layout = replace(moved, overlaps=old.overlaps, issues=old.issues)  # type: ignore[arg-type]
        plane, sensor = self._plane_issues, self._sensor_layout.issues if self._sensor_layout else {}
        self.issues = {i: plane.get(i, []) + sensor.get(i, []) for i in sorted(set(plane) | set(sensor))}
        self.canvas.show_issues(plane)
        self.table_model.set_lenslets(shown)
        self.table_model.set_issues(self.issues)
        self.render_selection(s)

    def render_selection(self, s: EditSession, *, from_table: bool = False) -> None:
        """Draw the selection (halos, table rows, sensor discs), the controls and the status line."""
        self.canvas.show_selection(s.selected, s.partners())
        if not from_table:
            self.table.select_rows(s.selected)
        self._show_sensor(s.shown, s.selected)
        self.edits.set_values(s.new_diameter_um, s.new_focal_length_mm)
        h = s.history
        self.edits.set_states(
            undo=h.undo_label() or None, redo=h.redo_label() or None, has_selection=bool(s.selected)
        )
        text, level = self._status(s)
        self.status_plain = text
        safe = text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
        self.status.setText(f"<span style='color:{STATUS_COLORS[level]}'>{safe}</span>")

    def _status(self, s: EditSession) -> tuple[str, str]:
        """The status line and its level: the summary of a layout edited elsewhere, else the checks."""
        if self.summary is not None and not s.last_error:
            return self.summary, "info"
        return status_line(
            s.shown,
            selected=len(s.selected),
            issues=self.issues,
            last_error=s.last_error,
            pupil_known=self.pupil_radius_um is not None,
            sensor_known=bool(self.sub_image_radius_um),
        )

    def set_summary(self, text: str | None, patch_note: str | None) -> None:
        """Describe a layout edited elsewhere: ``text`` replaces the status line's checks of the
        lenslets shown, ``patch_note`` the sensor view's overlap status (None: the checks again)."""
        self.summary = text
        self.sensor_view.patch_note = patch_note

    def _layout_of(self, shown: tuple[LensletSpec, ...], *, checks: bool) -> SensorLayout | None:
        if self.sub_image_radius_um is None:
            return None
        return sensor_layout(
            shown,
            sub_image_radius_um=self.sub_image_radius_um,
            sensor_size_um=self.sensor_size_um,
            magnification=self.magnification,
            tolerance_um=None if self.pixel_pitch_um is None else 0.5 * self.pixel_pitch_um,
            checks=checks,
        )

    def _show_sensor(self, shown: tuple[LensletSpec, ...], selected: list[int]) -> None:
        m = self.magnification
        self.sensor_view.show_layout(
            self._sensor_layout,
            self.sensor_size_um,
            [self._colors[lens.focal_length_mm] for lens in shown],
            [(m * lens.center_um[0], m * lens.center_um[1]) for lens in shown],
            selected,
        )
