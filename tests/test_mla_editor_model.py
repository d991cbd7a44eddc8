"""The MLA editor's Qt-free model: symmetric edits, snapping, undo/redo, checks, presets, sessions.

Exact comparisons (``==`` on lenslet tuples) are intended: edits round centres to
1e-6 um like the engine's layouts, and every expected value below is a float that
rounding leaves unchanged. Where a rotation is involved the tolerance is 1e-6 um
(the rounding step).
"""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace

import pytest

from lfm_studio.engine.design import LensletSpec, MLASpec, load_preset
from lfm_studio.widgets.mla_editor import model as model
from lfm_studio.widgets.mla_editor.checks import mla_issues, sensor_layout, summary
from lfm_studio.widgets.mla_editor.presets import PresetParams, build_preset, estimate_params
from lfm_studio.widgets.mla_editor.session import EditSession, status_line
from lfm_studio.widgets.mla_editor.symmetry import Symmetry


def lens(x: float, y: float, d: float = 100.0, f: float = 3.0) -> LensletSpec:
    return LensletSpec(center_um=(x, y), aperture_diameter_um=d, focal_length_mm=f)


def centers(lenslets) -> list[tuple[float, float]]:
    return [item.center_um for item in lenslets]


def test_model_modules_import_without_qt():
    probe = (
        "import sys\n"
        "import lfm_studio.widgets.mla_editor.model, lfm_studio.widgets.mla_editor.session\n"
        "import lfm_studio.widgets.mla_editor.checks, lfm_studio.widgets.mla_editor.presets\n"
        "print(','.join(m for m in ('PySide6', 'PyQt5', 'PyQt6', 'qtpy', 'pyqtgraph') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == ""


@pytest.mark.parametrize(
    ("symmetry", "order"),
    [
        (Symmetry(), 1),
        (Symmetry(mirror_x=True), 2),
        (Symmetry(mirror_x=True, mirror_y=True), 4),
        (Symmetry(rotation=6), 6),
        (Symmetry(mirror_x=True, rotation=3), 6),  # dihedral D3
        (Symmetry(mirror_y=True, rotation=4), 8),  # dihedral D4
    ],
)
def test_symmetry_group_order(symmetry, order):
    assert len(symmetry.group) == order
    assert symmetry.group[0] == (1.0, 0.0, 0.0, 1.0)


def test_symmetry_rejects_bad_rotation():
    with pytest.raises(ValueError, match="rotation must be 1"):
        Symmetry(rotation=0)
    with pytest.raises(TypeError, match="rotation must be an int"):
        Symmetry(rotation=True)


def test_orbit_and_projector():
    assert Symmetry(mirror_x=True).orbit((100.0, 50.0)) == [(100.0, 50.0), (-100.0, 50.0)]
    assert Symmetry(mirror_x=True).orbit((0.0, 50.0)) == [(0.0, 50.0)]  # on the mirror axis: itself
    assert len(Symmetry(rotation=6).orbit((1000.0, 0.0))) == 6
    # A point on the y axis keeps mirror-x symmetry only by moving along y.
    assert Symmetry(mirror_x=True).projector((0.0, 50.0)) == (0.0, 0.0, 0.0, 1.0)
    assert Symmetry(rotation=6).projector((0.0, 0.0)) == pytest.approx((0.0, 0.0, 0.0, 0.0), abs=1e-12)


def test_move_without_symmetry_and_with_snap():
    start = (lens(0, 0), lens(300, 0), lens(600, 0))
    moved = model.move(start, [0, 1], (10.0, -20.0))
    assert centers(moved) == [(10.0, -20.0), (310.0, -20.0), (600.0, 0.0)]
    # Snapping puts the grabbed (anchor) lenslet on the grid; the others keep their offsets.
    snapped = model.move(start, [1, 0], (103.0, 48.0), anchor=1, snap_pitch_um=50.0)
    assert centers(snapped)[1] == (400.0, 50.0)
    assert centers(snapped)[0] == (100.0, 50.0)
    assert snapped[2] == start[2]


def test_move_keeps_mirror_and_rotation_symmetry():
    pair = (lens(500, 0), lens(-500, 0), lens(0, 500))
    moved = model.move(pair, [0], (10.0, 20.0), symmetry=Symmetry(mirror_x=True))
    assert centers(moved)[:2] == [(510.0, 20.0), (-510.0, 20.0)]
    assert moved[2] == pair[2]
    on_axis = model.move(pair, [2], (30.0, 40.0), symmetry=Symmetry(mirror_x=True))
    assert centers(on_axis)[2] == (0.0, 540.0)  # slides along the mirror axis
    ring = tuple(lens(1000 * math.cos(k * math.pi / 3), 1000 * math.sin(k * math.pi / 3)) for k in range(6))
    grown = model.move((lens(0, 0), *ring), [1], (100.0, 0.0), symmetry=Symmetry(rotation=6))
    assert centers(grown)[0] == (0.0, 0.0)
    for item in grown[1:]:
        assert math.hypot(*item.center_um) == pytest.approx(1100.0, abs=1e-6)  # rounding step 1e-6 um


def test_add_delete_and_set_value_with_partners():
    start = (lens(0, 0),)
    added, new = model.add(
        start, (300.0, 100.0), diameter_um=80.0, focal_length_mm=4.0, symmetry=Symmetry(mirror_x=True)
    )
    assert new == [1, 2]
    assert centers(added)[1:] == [(300.0, 100.0), (-300.0, 100.0)]
    assert {item.aperture_diameter_um for item in added[1:]} == {80.0}
    _, new = model.add(
        start, (0.0, 400.0), diameter_um=80.0, focal_length_mm=4.0, symmetry=Symmetry(mirror_x=True)
    )
    assert new == [1]  # on the axis: its own partner
    resized = model.set_value(added, [1], "diameter_um", 120.0, symmetry=Symmetry(mirror_x=True))
    assert [item.aperture_diameter_um for item in resized] == [100.0, 120.0, 120.0]
    assert centers(model.delete(added, [2], symmetry=Symmetry(mirror_x=True))) == [(0.0, 0.0)]
    assert len(model.delete(added, [2])) == 2


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("diameter_um", -5.0, "aperture_diameter_um must be a finite number > 0 um; got -5 um"),
        ("focal_length_mm", 0.0, "focal_length_mm must be a finite number > 0 mm; got 0 mm"),
        ("x_um", math.nan, "x_um must be a finite number in µm"),
    ],
)
def test_set_value_refuses_invalid_values_with_reason(field, value, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        model.set_value((lens(0, 0),), [0], field, value)


def test_parse_value():
    assert model.parse_value("x_um", "1,5") == 1.5
    assert model.parse_value("diameter_um", " 150 um") == 150.0
    assert model.parse_value("diameter_um", "150 µm") == 150.0
    assert model.parse_value("focal_length_mm", "26mm") == 26.0
    with pytest.raises(
        ValueError,
        match=r"focal_length_mm must be a number; got 'abc' \(units: mm, nm, µm, m\)\. Fix: type a number from",
    ):
        model.parse_value("focal_length_mm", "abc")
    with pytest.raises(ValueError, match="x_um cannot be NaN"):  # the policy of every numeric field
        model.parse_value("x_um", "nan")


def test_history_restores_exact_lists():
    a, b, c = (lens(0, 0),), (lens(0, 0), lens(200, 0)), (lens(10, 0), lens(200, 0))
    history = model.EditHistory(a)
    assert not history.can_undo() and history.undo() is None
    assert history.push(b, "add") and history.push(c, "move")
    assert not history.push(c, "no-op")
    assert history.undo_label() == "move"
    assert history.undo() == b and history.undo() == a
    assert history.redo() == b and history.redo_label() == "move"
    history.push((lens(5, 5),), "other")
    assert not history.can_redo()
    limited = model.EditHistory(a, limit=2)
    for k in range(5):
        limited.push((lens(k, 1),))
    assert [limited.undo() is not None for _ in range(3)] == [True, True, False]


def test_as_lenslets_reports_index_and_reason():
    with pytest.raises(ValueError, match="lenslet 1: aperture_diameter_um must be"):
        model.as_lenslets(
            [lens(0, 0), {"center_um": (0, 0), "aperture_diameter_um": -1, "focal_length_mm": 3}]
        )


def test_mla_issues_overlap_and_pupil():
    layout = (lens(0, 0), lens(80, 0), lens(0, 950), lens(0, 1200))
    issues = mla_issues(layout, 1000.0)
    assert issues[0] == ["overlaps lenslet 1 by 20 µm"]  # radii 50 + 50 - distance 80
    assert issues[1] == ["overlaps lenslet 0 by 20 µm"]
    assert 2 not in issues  # reaches exactly the pupil rim: touching is allowed
    assert issues[3] == ["centre 1200 µm from the axis, outside the pupil (radius 1000 µm)"]
    vignetted = mla_issues((lens(0, 960),), 1000.0)
    assert vignetted[0] == ["reaches 1010 µm, beyond the pupil radius 1000 µm (vignetted)"]
    assert mla_issues(layout[:1], None) == {}
    # The status summary names each overlapping pair once.
    assert summary(issues, limit=10).count("overlaps") == 1


def test_sensor_layout_overlaps_and_edges():
    layout = sensor_layout(
        (lens(0, 0), lens(150, 0), lens(900, 0), lens(0, 950), lens(2000, 0)),
        sub_image_radius_um=100.0,
        sensor_size_um=(2000.0, 2000.0),
    )
    assert layout.overlaps == ((0, 1, 50.0),)
    assert layout.issues[0] == ["sub-image overlaps that of lenslet 1 by 50 µm"]
    assert 2 not in layout.issues  # its disc touches the sensor edge exactly
    assert layout.issues[3] == ["sub-image cut by the edge of the 2000 x 2000 µm sensor"]
    assert layout.issues[4] == ["sub-image centred off the 2000 x 2000 µm sensor"]
    scaled = sensor_layout((lens(100, 0),), sub_image_radius_um=10.0, sensor_size_um=None, magnification=2.0)
    assert scaled.centers_um == ((200.0, 0.0),)


def test_presets_are_the_engine_builders():
    params = PresetParams(pitch_um=150.0, count=5, focal_lengths_mm=(3.0,), aperture_diameter_um=140.0)
    square = MLASpec.square_grid(150.0, 5, 3.0, fill_factor=140.0 / 150.0, keep_within_diameter_um=600.0)
    assert build_preset("square", params, pupil_radius_um=300.0) == square.lenslets
    hexa = MLASpec.hex_grid(150.0, 3.0, rings=5, fill_factor=140.0 / 150.0)
    assert build_preset("hex", params) == hexa.lenslets
    xlfm = load_preset("xlfm_cong2017").mla.lenslets
    assert build_preset("xlfm", estimate_params(xlfm)) == xlfm
    with pytest.raises(ValueError, match="complete-shell counts"):
        build_preset("xlfm", PresetParams(count=5))
    with pytest.raises(ValueError, match="preset must be one of"):
        build_preset("triangle", params)  # type: ignore[arg-type]


def test_session_drag_preview_commit_and_refusals():
    session = EditSession((lens(0, 0), lens(300, 0)))
    session.symmetry = Symmetry()
    session.begin_drag(1, "move", 300.0, 0.0)
    assert session.selected == [1]
    preview = session.drag_to(320.0, 10.0)
    assert centers(preview) == [(0.0, 0.0), (320.0, 10.0)]
    assert session.lenslets[1].center_um == (300.0, 0.0)  # nothing committed while dragging
    assert session.drag_to(320.0, 10.0) is None  # unchanged: no second preview
    assert session.end_drag(330.0, 10.0)
    assert session.lenslets[1].center_um == (330.0, 10.0)
    session.begin_drag(1, "resize", 330.0, 10.0)
    session.drag_to(330.0, 10.0)  # zero diameter: refused silently, the last valid frame stays
    assert session.end_drag(330.0, 70.0)
    assert session.lenslets[1].aperture_diameter_um == 120.0
    assert not session.edit_cell(0, "diameter_um", "-3")
    assert (
        "lenslet 0 diameter_um: diameter_um -3 is out of range. Fix: type a number from 0.001"
        in session.last_error
    )
    assert not session.edit_cell(7, "x_um", "1")
    assert "there is no lenslet 7" in session.last_error
    assert session.edit_cell(0, "x_um", "-50")
    assert session.last_error == ""
    text, level = status_line(
        session.lenslets, selected=1, issues={}, last_error="", pupil_known=True, sensor_known=False
    )
    assert level == "ok" and text.startswith("2 lenslets, focal lengths 3 mm; 1 selected")
    assert session.undo() and session.undo() and session.undo()
    assert session.lenslets == (lens(0, 0), lens(300, 0))
    assert not session.undo()


def test_add_free_takes_the_nearest_free_lattice_site_of_a_hex_array_with_the_selected_shape():
    hexes = MLASpec.hex_grid(300.0, 2.0, rings=1, fill_factor=0.9).lenslets  # 7 circles, 270 um apertures
    session = EditSession(hexes)
    session.select([3])
    added = session.add_free((0.0, 0.0), pupil_radius_um=2000.0)
    assert added == [7] and session.last_error == ""
    new = session.lenslets[7]
    # one lattice step beyond a lenslet of the outer ring (sqrt(3) x 300 um from the centre: a hex site)
    assert math.hypot(*new.center_um) == pytest.approx(300.0 * math.sqrt(3.0), abs=1e-5)
    assert (new.shape, new.aperture_diameter_um) == (hexes[3].shape, hexes[3].aperture_diameter_um)
    assert mla_issues(session.lenslets, 2000.0) == {}


def test_add_free_keeps_symmetric_partners_clear_and_refuses_a_full_pupil():
    session = EditSession([lens(0.0, 0.0)])  # one 100 um circle
    session.symmetry = Symmetry(mirror_x=True)
    added = session.add_free((0.0, 0.0), pupil_radius_um=1000.0)
    assert len(added) == 2  # a site and its mirror image, both clear
    assert mla_issues(session.lenslets, 1000.0) == {}
    full = EditSession([lens(0.0, 0.0, d=180.0)])  # fills a 100 um pupil: nothing else fits
    assert full.add_free((0.0, 0.0), pupil_radius_um=100.0) == []
    assert full.last_error.startswith("add: no free spot inside the pupil") and len(full.lenslets) == 1


def test_an_empty_layout_says_so_without_an_ok():
    """After deleting every lenslet the line read "no lenslets ... OK: no overlapping lenslets ..." in green."""
    text, level = status_line((), selected=0, issues={}, last_error="", pupil_known=True, sensor_known=True)
    assert level == "error" and text.startswith("no lenslets") and "OK" not in text


def test_matching_preset_names_the_builder_that_rebuilds_a_layout():
    from lfm_studio.widgets.mla_editor.presets import matching_preset

    assert matching_preset(load_preset("flfm_guo2019").mla.lenslets) == ("square", 3)
    assert matching_preset(load_preset("xlfm_cong2017").mla.lenslets) == ("xlfm", 27)
    assert matching_preset(build_preset("hex", PresetParams(300.0, 2, (3.0,), 200.0))) == ("hex", 2)
    assert matching_preset(load_preset("flfm_guo2019").mla.lenslets[:8]) == ("custom", 0)  # one missing
    assert matching_preset(()) == ("custom", 0)


def replace_lens(lens: LensletSpec, **changes: object) -> LensletSpec:
    """``lens`` with ``changes`` (validated again)."""
    return LensletSpec(**{**lens.model_dump(), **changes})


def test_a_preset_rebuilds_the_lenslet_shape_it_reads_off_the_layout():
    """The FLFM preset's row read "Square grid", but applying it built circles: no shape option."""
    from lfm_studio.widgets.mla_editor.presets import matching_preset

    flfm = load_preset("flfm_guo2019").mla.lenslets  # 3 x 3 square apertures
    kind, count = matching_preset(flfm)
    params = estimate_params(flfm)
    assert params.lenslet_shape == "square"
    rebuilt = build_preset(kind, replace(params, count=count))  # what Apply builds from the row
    assert rebuilt == tuple(flfm)
    circles = tuple(replace_lens(lens, shape="circle") for lens in flfm)
    assert matching_preset(circles) == ("square", 3) and estimate_params(circles).lenslet_shape == "circle"
    squares = build_preset("hex", PresetParams(300.0, 1, (3.0,), 200.0, "square"))
    assert {lens.shape for lens in squares} == {"square"} and matching_preset(squares) == ("hex", 1)
    mixed = (*flfm[:8], replace_lens(flfm[8], shape="circle"))
    assert matching_preset(mixed) == ("custom", 0)  # no preset builds one circle among squares


def test_a_refused_edit_writes_the_engines_um_as_micrometres():
    """The editor's status line shows the engine's refusal; the studio writes µm everywhere else."""
    session = EditSession([lens(0.0, 0.0)])
    assert session.refuse("aperture_diameter_um -5 um must be > 0") is False
    assert session.last_error == "aperture_diameter_um -5 µm must be > 0"
