"""The MLA layout editor driven both ways: state -> view (set_lenslets) and view -> state (mouse, keys, table).

Exact ``==`` on lenslet tuples is intended (edits round centres to 1e-6 um; the
expected values are unchanged by that rounding). Mouse positions go through the
screen, so positions reached by dragging are compared to within 1.5 screen pixels
(in micrometres) unless snapping makes them exact.
"""

from __future__ import annotations

import html
import math

import pytest
from qtpy.QtCore import QEvent, QPoint, QPointF, Qt
from qtpy.QtGui import QAction, QKeySequence, QMouseEvent
from qtpy.QtTest import QTest
from qtpy.QtWidgets import QApplication, QLineEdit, QMainWindow

from lfm_studio.engine.design import LensletSpec, MLASpec, load_preset
from lfm_studio.ui.edits import try_changes
from lfm_studio.widgets.mla_editor import MLAEditor
from lfm_studio.widgets.mla_editor.presets import PresetParams, estimate_params
from lfm_studio.widgets.mla_editor.style import ISSUE
from lfm_studio.widgets.mla_editor.symmetry import Symmetry

PUPIL_UM = 1000.0


def lens(x: float, y: float, d: float = 200.0, f: float = 3.0) -> LensletSpec:
    return LensletSpec(center_um=(x, y), aperture_diameter_um=d, focal_length_mm=f)


START = (lens(0, 0), lens(400, 0), lens(-400, 0, d=150.0, f=4.0))


@pytest.fixture
def editor(qtbot):
    widget = MLAEditor(START, pupil_radius_um=PUPIL_UM, sensor_size_um=(3000.0, 3000.0))
    qtbot.addWidget(widget)
    widget.resize(1100, 760)
    widget.show()
    qtbot.waitExposed(widget)
    widget.fit()
    QApplication.processEvents()
    return widget


class Recorder:
    """Collects what the editor emits."""

    def __init__(self, editor: MLAEditor) -> None:
        self.committed: list[tuple] = []
        self.previews: list[tuple] = []
        editor.lensletsCommitted.connect(self.committed.append)
        editor.lensletsPreview.connect(self.previews.append)


# ----- mouse helpers: real events on the canvas viewport (pyqtgraph turns them into clicks and drags) -----


def _viewport_point(editor: MLAEditor, x_um: float, y_um: float) -> QPoint:
    return editor.canvas.mapFromScene(editor.canvas.view_to_scene(x_um, y_um))


def _send(editor, kind, point: QPoint, button, buttons, modifiers=Qt.KeyboardModifier.NoModifier) -> None:
    viewport = editor.canvas.viewport()
    local = QPointF(point)
    event = QMouseEvent(kind, local, QPointF(viewport.mapToGlobal(point)), button, buttons, modifiers)
    QApplication.sendEvent(viewport, event)


def mouse_drag(qtbot, editor, start_um, end_um, steps=6, modifiers=Qt.KeyboardModifier.NoModifier):
    left = Qt.MouseButton.LeftButton
    a, b = _viewport_point(editor, *start_um), _viewport_point(editor, *end_um)
    _send(editor, QEvent.Type.MouseButtonPress, a, left, left, modifiers)
    for k in range(1, steps + 1):
        qtbot.wait(15)  # pyqtgraph drops mouse moves closer than 10 ms apart
        p = a + (b - a) * k / steps
        _send(editor, QEvent.Type.MouseMove, p, Qt.MouseButton.NoButton, left, modifiers)
    qtbot.wait(15)
    _send(editor, QEvent.Type.MouseButtonRelease, b, left, Qt.MouseButton.NoButton, modifiers)


def mouse_click(qtbot, editor, at_um, modifiers=Qt.KeyboardModifier.NoModifier, double=False):
    left, none = Qt.MouseButton.LeftButton, Qt.MouseButton.NoButton
    p = _viewport_point(editor, *at_um)
    _send(editor, QEvent.Type.MouseButtonPress, p, left, left, modifiers)
    _send(editor, QEvent.Type.MouseButtonRelease, p, left, none, modifiers)
    if double:
        _send(editor, QEvent.Type.MouseButtonDblClick, p, left, left, modifiers)
        _send(editor, QEvent.Type.MouseButtonRelease, p, left, none, modifiers)
    qtbot.wait(5)


def pixel_um(editor) -> float:
    px = editor.canvas.getViewBox().viewPixelSize()
    return max(abs(px[0]), abs(px[1]))


# ----- state -> view -----


def test_set_lenslets_updates_table_and_canvas_without_signals(editor, qtbot):
    rec = Recorder(editor)
    new = (lens(100, 50, d=300.0), lens(-300, -200, f=5.0))
    editor.set_lenslets(new)
    assert rec.committed == [] and rec.previews == []
    assert editor.lenslets() == new
    model = editor.table_model
    assert model.rowCount() == 2
    assert [model.index(0, c).data() for c in range(4)] == ["100", "50", "300", "3"]
    assert model.index(1, 3).data() == "5"
    rect = editor.canvas.body_item(0).rect()
    assert (rect.center().x(), rect.center().y(), rect.width()) == (100.0, 50.0, 300.0)
    assert editor.can_undo()  # an external change is one undo step...
    editor.set_lenslets(START, reset_history=True)
    assert not editor.can_undo()  # ...unless the history is reset


def test_another_layout_sets_the_size_row_and_the_size_of_added_lenslets(editor):
    """The lenslet Ø / f row follows the layout put in force, not the previous design's lenslets."""
    editor.set_lenslets((lens(0, 0, d=600.0, f=16.8), lens(700, 0, d=600.0, f=16.8)))
    assert (editor.edits.diameter.value(), editor.edits.focal.value()) == (600.0, 16.8)
    added = editor.add_lenslet(-700.0, 0.0)
    assert [
        (editor.lenslets()[i].aperture_diameter_um, editor.lenslets()[i].focal_length_mm) for i in added
    ] == [(600.0, 16.8)]


# ----- table -> state -----


def test_table_edit_through_the_cell_editor_commits_the_new_value(editor, qtbot):
    rec = Recorder(editor)
    index = editor.table_model.index(1, 0)
    editor.table.setCurrentIndex(index)
    editor.table.edit(index)
    qtbot.wait(10)
    line = editor.table.viewport().findChild(QLineEdit)
    assert line is not None, "the cell editor is a line edit (text, not a 2-decimal spin box)"
    line.selectAll()
    QTest.keyClicks(line, "250.5")
    QTest.keyClick(line, Qt.Key.Key_Return)
    qtbot.wait(10)
    assert len(rec.committed) == 1
    assert rec.committed[0][1].center_um == (250.5, 0.0)
    assert editor.lenslets()[1].center_um == (250.5, 0.0)
    assert editor.table_model.index(1, 0).data() == "250.5"
    assert editor.canvas.body_item(1).rect().center().x() == 250.5


@pytest.mark.parametrize(
    ("column", "text", "reason"),
    [
        (2, "-5", "diameter_um -5 is out of range. Fix: type a number from 0.001 to 1000000 µm"),
        (3, "abc", "focal_length_mm must be a number; got 'abc'"),
        (0, "nan", "x_um cannot be NaN (not a number)"),
        (3, "1,000.5", "'1,000.5' has 2 decimal marks"),
    ],
)
def test_invalid_table_values_are_refused_with_the_reason(editor, column, text, reason):
    rec = Recorder(editor)
    assert editor.table_model.setData(editor.table_model.index(0, column), text)
    assert rec.committed == []
    assert editor.lenslets() == START
    assert reason in editor.last_error()
    assert editor.status_text().startswith("Refused: lenslet 0")
    assert html.escape(reason, quote=False) in editor.status.text()  # shown in the status line
    editor.table_model.setData(editor.table_model.index(0, 3), "7")  # a valid edit clears the error
    assert editor.last_error() == "" and editor.lenslets()[0].focal_length_mm == 7.0


# ----- canvas gestures -----


def test_mouse_drag_previews_then_commits_once(editor, qtbot):
    rec = Recorder(editor)
    mouse_drag(qtbot, editor, (400.0, 0.0), (500.0, 100.0))
    assert len(rec.previews) >= 2
    assert len(rec.committed) == 1
    x, y = rec.committed[0][1].center_um
    tol = 1.5 * pixel_um(editor)
    assert abs(x - 500.0) < tol and abs(y - 100.0) < tol
    assert rec.committed[0][0] == START[0] and rec.committed[0][2] == START[2]
    assert editor.selected_indices() == [1]


def test_drag_api_with_snapping_rounds_to_the_grid(editor, qtbot):
    rec = Recorder(editor)
    editor.set_snap(50.0)
    editor.begin_drag(1, "move", 400.0, 0.0)
    editor.drag_to(430.0, 12.0)
    editor.drag_to(503.0, 48.0)
    assert rec.committed == [] and len(rec.previews) == 2
    assert rec.previews[0][1].center_um == (450.0, 0.0)
    editor.end_drag(503.0, 48.0)
    assert len(rec.committed) == 1
    assert editor.lenslets()[1].center_um == (500.0, 50.0)


def test_mouse_drag_with_snapping_lands_on_the_grid(editor, qtbot):
    editor.set_snap(100.0)
    mouse_drag(qtbot, editor, (400.0, 0.0), (480.0, 130.0))
    assert editor.lenslets()[1].center_um == (500.0, 100.0)


def test_escape_cancels_a_drag(editor, qtbot):
    rec = Recorder(editor)
    editor.begin_drag(1, "move", 400.0, 0.0)
    editor.drag_to(600.0, 0.0)
    editor.canvas.setFocus()
    QTest.keyClick(editor.canvas, Qt.Key.Key_Escape)
    assert rec.committed == [] and rec.previews[-1] == START
    editor.end_drag(600.0, 0.0)  # the release after a cancel commits nothing
    assert rec.committed == [] and editor.lenslets() == START


def test_rim_drag_resizes_the_selection(editor, qtbot):
    rec = Recorder(editor)
    editor.set_selection([1])
    mouse_drag(qtbot, editor, (500.0, 0.0), (560.0, 0.0))  # rim of lenslet 1 (radius 100 um)
    assert len(rec.committed) == 1
    assert abs(editor.lenslets()[1].aperture_diameter_um - 320.0) < 3 * pixel_um(editor)
    assert editor.lenslets()[1].center_um == (400.0, 0.0)


def test_click_shift_click_and_rubber_band_select(editor, qtbot):
    mouse_click(qtbot, editor, (400.0, 0.0))
    assert editor.selected_indices() == [1]
    mouse_click(qtbot, editor, (-400.0, 0.0), modifiers=Qt.KeyboardModifier.ShiftModifier)
    assert editor.selected_indices() == [1, 2]
    assert editor.table.selected_rows() == [1, 2]
    mouse_click(qtbot, editor, (0.0, 600.0))  # empty space
    assert editor.selected_indices() == []
    mouse_drag(qtbot, editor, (-200.0, 300.0), (600.0, -300.0))  # a band around lenslets 0 and 1
    assert editor.selected_indices() == [0, 1]


def test_table_selection_selects_on_the_canvas(editor):
    editor.table.selectRow(2)
    assert editor.selected_indices() == [2]
    assert editor.canvas._halos[2].isVisible() and not editor.canvas._halos[0].isVisible()


def test_double_click_adds_with_the_last_used_size(editor, qtbot):
    rec = Recorder(editor)
    editor.set_selection([2])  # diameter 150 um, f 4 mm: the size new lenslets get
    mouse_click(qtbot, editor, (0.0, 500.0), double=True)
    assert len(rec.committed) == 1
    new = editor.lenslets()[3]
    tol = 1.5 * pixel_um(editor)
    assert abs(new.center_um[0]) < tol and abs(new.center_um[1] - 500.0) < tol
    assert (new.aperture_diameter_um, new.focal_length_mm) == (150.0, 4.0)
    assert editor.selected_indices() == [3]


def test_add_button_and_delete_key(editor, qtbot):
    rec = Recorder(editor)
    editor.set_snap(10.0)
    editor.edits.add.click()
    assert len(editor.lenslets()) == 4 and len(rec.committed) == 1
    editor.set_selection([0, 3])
    editor.canvas.setFocus()
    QTest.keyClick(editor.canvas, Qt.Key.Key_Delete)
    assert len(rec.committed) == 2
    assert editor.lenslets() == START[1:]
    assert editor.selected_indices() == []


def test_add_button_grows_the_flfm_square_array_by_a_free_square_lenslet(qtbot):
    """Add used to drop a circle on the view centre, on top of the middle square: refused at once."""
    design = load_preset("flfm_guo2019")  # 3x3 square lenslets, 600 um pitch, touching
    widget = MLAEditor(design.mla.lenslets, pupil_radius_um=design.pupil_diameter_at_mla / 2.0 * 1e6)
    qtbot.addWidget(widget)
    widget.resize(1100, 760)
    widget.show()
    qtbot.waitExposed(widget)
    widget.fit()
    rec = Recorder(widget)
    widget.edits.add.click()
    lenslets = widget.lenslets()
    assert len(lenslets) == 10 and len(rec.committed) == 1 and widget.last_error() == ""
    old, new = lenslets[0], lenslets[-1]
    assert (new.shape, new.aperture_diameter_um, new.focal_length_mm) == (
        "square", old.aperture_diameter_um, old.focal_length_mm,
    )  # fmt: skip
    assert widget.issues() == {}  # clear of the others, inside the pupil
    outcome = try_changes(design, {"mla.lenslets": lenslets})
    assert outcome.ok, outcome.error  # the studio accepts the layout
    assert sorted(abs(v) for v in new.center_um) == [0.0, 1200.0]  # the lattice site next to the middle row
    widget.edits.add.click()
    assert len(widget.lenslets()) == 11 and widget.issues() == {}


def test_undo_redo_restore_exact_lists_by_keys_and_buttons(editor, qtbot):
    rec = Recorder(editor)
    states = [editor.lenslets()]
    editor.add_lenslet(0.0, 600.0)
    states.append(editor.lenslets())
    editor.set_selection([1])
    editor.set_selected_diameter(250.0)
    states.append(editor.lenslets())
    editor.edit_cell(0, "y_um", "-300")
    states.append(editor.lenslets())
    assert len(rec.committed) == 3
    editor.canvas.setFocus()
    for expected in reversed(states[:-1]):
        QTest.keyClick(editor.canvas, Qt.Key.Key_Z, Qt.KeyboardModifier.ControlModifier)
        assert editor.lenslets() == expected
    assert not editor.can_undo() and not editor.undo()
    assert rec.committed[-3:] == [states[2], states[1], states[0]]
    QTest.keyClick(
        editor.canvas, Qt.Key.Key_Z, Qt.KeyboardModifier.ControlModifier | Qt.KeyboardModifier.ShiftModifier
    )
    assert editor.lenslets() == states[1]
    QTest.keyClick(editor.canvas, Qt.Key.Key_Y, Qt.KeyboardModifier.ControlModifier)
    editor.edits.redo.click()
    assert editor.lenslets() == states[3] and not editor.can_redo()
    assert not editor.edits.redo.isEnabled() and editor.edits.undo.isEnabled()
    assert len(rec.committed) == 3 + 3 + 3


def test_ctrl_z_reaches_the_editor_inside_a_window_with_its_own_undo_shortcut(qtbot):
    window = QMainWindow()
    qtbot.addWidget(window)
    editor = MLAEditor(START)
    window.setCentralWidget(editor)
    fired = []
    action = QAction("Undo design change", window)
    action.setShortcut(QKeySequence("Ctrl+Z"))
    action.triggered.connect(fired.append)
    window.addAction(action)
    window.show()
    qtbot.waitExposed(window)
    editor.add_lenslet(0.0, 600.0)
    editor.canvas.setFocus()
    QTest.keyClick(editor.canvas, Qt.Key.Key_Z, Qt.KeyboardModifier.ControlModifier)
    assert editor.lenslets() == START
    assert fired == []


# ----- symmetric editing -----


def test_mirror_x_add_creates_the_partner_and_drag_moves_it(editor, qtbot):
    rec = Recorder(editor)
    editor.set_symmetry(Symmetry(mirror_x=True))
    added = editor.add_lenslet(300.0, 500.0)
    assert added == [3, 4]
    assert [item.center_um for item in editor.lenslets()[3:]] == [(300.0, 500.0), (-300.0, 500.0)]
    editor.set_selection([3])
    assert editor.canvas._halos[4].isVisible()  # the partner is shown
    editor.begin_drag(3, "move", 300.0, 500.0)
    editor.drag_to(350.0, 520.0)
    assert rec.previews[-1][4].center_um == (-350.0, 520.0)
    editor.end_drag(350.0, 520.0)
    assert editor.lenslets()[4].center_um == (-350.0, 520.0)
    assert editor.lenslets()[1].center_um == (400.0, 0.0)  # not a partner: untouched
    editor.set_selected_focal_length(6.0)
    assert editor.lenslets()[4].focal_length_mm == 6.0
    editor.delete_selected()
    assert editor.lenslets() == START


def test_rotation_symmetry_moves_every_partner(qtbot):
    ring = MLASpec.hex_grid(300.0, 3.0, rings=1, fill_factor=0.5).lenslets
    editor = MLAEditor(ring, pupil_radius_um=PUPIL_UM)
    qtbot.addWidget(editor)
    editor.set_symmetry(Symmetry(rotation=6))
    outer = next(i for i, item in enumerate(ring) if item.center_um == (300.0, 0.0))
    editor.begin_drag(outer, "move", 300.0, 0.0)
    editor.end_drag(400.0, 0.0)
    radii = sorted(
        round((x * x + y * y) ** 0.5, 4) for x, y in (item.center_um for item in editor.lenslets())
    )
    assert radii == [0.0] + [400.0] * 6


# ----- highlights -----


def test_overlap_and_outside_highlighted_with_reason(editor):
    editor.set_lenslets((lens(0, 0), lens(150, 0), lens(0, 950), lens(0, 1500)))
    issues = editor.issues()
    assert issues[0] == ["overlaps lenslet 1 by 50 µm"]
    assert issues[2] == ["reaches 1050 µm, beyond the pupil radius 1000 µm (vignetted)"]
    assert issues[3] == ["centre 1500 µm from the axis, outside the pupil (radius 1000 µm)"]
    for i in (0, 1, 2, 3):
        item = editor.canvas.body_item(i)
        assert item.pen().color().name() == ISSUE.name()
        assert issues[i][0] in item.toolTip()
    assert "overlaps lenslet 1 by 50 µm" in editor.status_text()
    assert editor.status_text().count("overlaps") == 1
    model = editor.table_model
    assert model.index(3, 0).data(Qt.ItemDataRole.ForegroundRole).name() == ISSUE.name()
    assert "outside the pupil" in model.index(3, 0).data(Qt.ItemDataRole.ToolTipRole)
    editor.set_lenslets(START)
    assert editor.issues() == {}
    assert editor.canvas.body_item(0).pen().color().name() != ISSUE.name()
    assert "OK: no overlapping lenslets, all inside the pupil" in editor.status_text()


def test_sensor_view_shows_sub_images_and_their_overlaps(editor):
    editor.set_sensor((3000.0, 3000.0), 150.0)
    assert len(editor.sensor_view.disc_items()) == 3
    assert editor.sensor_view.overlap_items() == []
    editor.set_sensor((3000.0, 3000.0), 250.0)  # 500 um discs, 400 um apart: two overlaps
    overlaps = editor.sensor_view.overlap_items()
    assert len(overlaps) == 2
    assert "overlaps that of lenslet 1 by 100 µm" in " ".join(editor.issues()[0])
    assert editor.sensor_view.disc_items()[0].pen().color().name() == ISSUE.name()
    editor.set_sensor((1000.0, 1000.0), 100.0, magnification=2.0)  # centres at +-800 um: off a 1 mm sensor
    assert editor.sensor_view.disc_items()[1].rect().center().x() == 800.0
    assert "sub-image centred off the 1000 x 1000 µm sensor" in editor.issues()[1]


def test_the_sensor_title_gives_the_overlap_status_a_line_of_its_own(editor):
    """At the default window the one-line title was cut before its most useful part ("… · no ov…")."""
    title = editor.sensor_view.getPlotItem().titleLabel
    editor.set_sensor((3000.0, 3000.0), 250.0)  # two overlaps
    first, status = title.text.split("<br>")
    assert "sub-images 500 µm across" in first and "2 overlap(s)" in status
    editor.set_sensor((3000.0, 3000.0), 150.0)
    assert title.text.split("<br>")[1] == "no overlap"
    width = title.item.boundingRect().width()  # the widest line
    assert width <= editor.sensor_view.getPlotItem().width()


# ----- presets -----


def test_presets_produce_the_builders_lenslets(editor):
    rec = Recorder(editor)
    params = PresetParams(pitch_um=220.0, count=7, focal_lengths_mm=(3.0, 3.3), aperture_diameter_um=200.0)
    assert editor.apply_preset("square", params)
    expected = MLASpec.square_grid(
        220.0, 7, 3.0, fill_factor=200.0 / 220.0, keep_within_diameter_um=2 * PUPIL_UM
    )
    assert editor.lenslets() == expected.lenslets
    assert editor.apply_preset("hex", PresetParams(pitch_um=220.0, count=2, aperture_diameter_um=200.0))
    expected = MLASpec.hex_grid(
        220.0, 26.0, rings=2, fill_factor=200.0 / 220.0, keep_within_diameter_um=2 * PUPIL_UM
    )
    assert editor.lenslets() == expected.lenslets
    assert len(rec.committed) == 2
    xlfm = load_preset("xlfm_cong2017").mla.lenslets
    assert editor.apply_preset("xlfm", estimate_params(xlfm))
    assert editor.lenslets() == xlfm
    editor.undo()
    assert editor.lenslets() == MLASpec.hex_grid(220.0, 26.0, rings=2, fill_factor=200.0 / 220.0).lenslets


def test_the_preset_row_shows_the_preset_of_the_layout_or_custom(qtbot, editor):
    """On the FLFM 3x3 design it showed "XLFM-like (two focal groups)", n = 27, f = 16.8 / 18.48 mm."""
    bar = editor.presets
    assert bar.current_kind() == "custom" and not bar.apply.isEnabled()  # 3 lenslets in a row: no preset
    flfm = load_preset("flfm_guo2019").mla.lenslets
    editor.set_lenslets(flfm)  # the studio opens another design
    assert (bar.kind.currentText(), bar.count.value()) == ("Square grid", 3)
    assert (bar.pitch.value(), bar.diameter.value(), bar.focal_a.value()) == (600.0, 600.0, 16.8)
    assert bar.apply.isEnabled()
    fresh = MLAEditor(load_preset("xlfm_cong2017").mla.lenslets)
    qtbot.addWidget(fresh)
    assert (fresh.presets.current_kind(), fresh.presets.count.value()) == ("xlfm", 27)


def test_applying_the_preset_the_row_names_rebuilds_the_layout_with_its_shape(editor):
    """The FLFM row read "Square grid" (square lenslets on screen), but Apply built circles."""
    design = load_preset("flfm_guo2019")
    bar, flfm = editor.presets, design.mla.lenslets
    editor.set_pupil_radius(design.pupil_diameter_at_mla / 2.0 * 1e6)  # as the studio sets it
    editor.set_lenslets(flfm)
    assert (bar.kind.currentText(), bar.shape.currentText()) == ("Square grid", "squares")
    bar.apply.click()  # Apply as the row reads
    assert editor.lenslets() == flfm and {lens.shape for lens in editor.lenslets()} == {"square"}
    bar.shape.setCurrentIndex(bar.shape.findData("circle"))
    bar.apply.click()
    assert [lens.center_um for lens in editor.lenslets()] == [lens.center_um for lens in flfm]
    assert {lens.shape for lens in editor.lenslets()} == {"circle"}
    assert (bar.kind.currentText(), bar.shape.currentText()) == ("Square grid", "circles")


def test_preset_row_applies_and_bad_preset_is_refused(editor):
    rec = Recorder(editor)
    editor.presets.kind.setCurrentIndex(editor.presets.kind.findData("xlfm"))  # the layout is custom
    editor.presets.count.setText("5")  # the xlfm preset needs complete shells (typed, applied)
    editor.presets.apply.click()
    assert rec.committed == [] and "complete-shell counts" in editor.last_error()
    editor.presets.count.setText("12")
    editor.presets.apply.click()
    assert len(rec.committed) == 1 and len(editor.lenslets()) == 12


def test_echoed_lenslets_do_not_disturb_a_drag_or_the_history(editor):
    rec = Recorder(editor)
    editor.begin_drag(1, "move", 400.0, 0.0)
    editor.drag_to(450.0, 0.0)
    editor.set_lenslets(rec.previews[-1])  # an application that echoes previews back
    editor.set_lenslets(START)  # ...or the committed layout
    editor.end_drag(460.0, 0.0)
    assert len(rec.committed) == 1 and editor.lenslets()[1].center_um == (460.0, 0.0)
    editor.set_lenslets(rec.committed[0])  # the commit coming back through the application state
    assert editor.undo() and editor.lenslets() == START and not editor.can_undo()


def test_unknown_sub_image_size_shows_centres_only(editor):
    editor.set_sensor((3000.0, 3000.0), 0.0)  # what an application passes when the field is unlimited
    assert editor.sensor_view.disc_items() == []
    assert "sub-images apart" not in editor.status_text()
    editor.set_sensor((500.0, 500.0), 0.0)  # lenslets 1 and 2 (x = +-400 um) are off a 0.5 mm sensor
    assert "sub-image centred off the 500 x 500 µm sensor" in editor.issues()[1]


def test_sub_image_overlaps_match_a_brute_force_search():
    import random

    from lfm_studio.engine.design.geometry import disc_overlaps  # what the editor's sensor check calls

    rng = random.Random(3)
    centers = [
        (rng.uniform(-5000, 5000), rng.uniform(-5000, 5000)) for _ in range(700)
    ]  # > one block of rows
    radius, tolerance = 400.0, 2.0
    brute = [
        (i, j, 2 * radius - math.dist(centers[i], centers[j]))
        for i in range(len(centers))
        for j in range(i + 1, len(centers))
        if 2 * radius - math.dist(centers[i], centers[j]) > tolerance
    ]
    found = disc_overlaps(centers, radius, tolerance)
    assert len(brute) > 100 and [p[:2] for p in found] == [p[:2] for p in brute]
    assert [p[2] for p in found] == pytest.approx([p[2] for p in brute], rel=1e-12)


def test_table_headers_are_never_clipped_in_a_narrow_editor(qtbot):
    """A narrow dock (the napari MLA editor beside other docks) read "liameter (um" and "al length (m":
    every column stays at least as wide as its header text, whose full meaning is in the tooltip."""
    from lfm_studio.widgets.mla_editor.table import HEADERS

    widget = MLAEditor(START, pupil_radius_um=PUPIL_UM, sensor_size_um=(3000.0, 3000.0))
    qtbot.addWidget(widget)
    widget.resize(400, 500)  # narrower than the canvas and the table want: both at their minimum
    widget.show()
    qtbot.waitExposed(widget)
    table, model = widget.table, widget.table_model
    header = table.horizontalHeader()
    texts = [model.headerData(i, Qt.Orientation.Horizontal) for i in range(model.columnCount())]
    assert tuple(texts) == HEADERS
    for i, text in enumerate(texts):
        assert header.sectionSize(i) >= header.fontMetrics().horizontalAdvance(text) + 8, (
            text,
            header.sectionSize(i),
        )
    tips = [model.headerData(i, Qt.Orientation.Horizontal, Qt.ItemDataRole.ToolTipRole) for i in range(4)]
    assert "diameter" in tips[2] and "focal length" in tips[3] and all("µm" in t or "mm" in t for t in tips)
