"""The parameter panel both ways: state -> fields, fields -> new design or a marked error."""

from __future__ import annotations

import pytest
from qtpy.QtCore import Qt
from qtpy.QtTest import QTest

from lfm_studio.engine.design import load_preset
from lfm_studio.ui.edits import apply_changes
from lfm_studio.ui.parameter_panel import ParameterPanel
from lfm_studio.ui.state import StudioState
from tests.ui.standins import small_fourier_design

NA = "objective.numerical_aperture"


@pytest.fixture(scope="module")
def design():
    return small_fourier_design()


@pytest.fixture
def panel(qtbot, design):
    state = StudioState(design)
    panel = ParameterPanel(state)
    qtbot.addWidget(panel)
    yield panel
    panel.disconnect_state()


def _set(panel, path, *values):
    """What a user does: type into the box(es) and press Enter."""
    for box, value in zip(panel.inputs[path].boxes, values, strict=False):
        _type(box, str(value))


def _type(box, text):
    box.setFocus()
    box.selectAll()
    QTest.keyClicks(box, text)
    QTest.keyClick(box, Qt.Key.Key_Return)


def test_fields_show_the_design_with_units(panel, design):
    assert panel.inputs[NA].value() == pytest.approx(0.95)
    assert panel.inputs["wavelength_nm"].boxes[0].suffix() == " nm"
    assert panel.inputs["camera.pixel_pitch_um"].boxes[0].suffix() == " µm"
    assert panel.inputs["objective.tube_lens_focal_length_mm"].boxes[0].suffix() == " mm"
    assert panel.inputs["camera.pixel_count"].value() == (256, 256)
    assert panel.inputs["depths.depth_range_um"].value() == (-10.0, 10.0)
    assert panel.inputs["relay.field_stop_diameter_mm"].value() == pytest.approx(2.0)
    assert panel.accuracy.currentText() == "preview"


def test_a_valid_edit_builds_a_new_design(panel, design):
    state = panel.state
    _set(panel, NA, 0.9)
    assert state.design.objective.numerical_aperture == pytest.approx(0.9)
    assert state.dirty and state.errors == {}
    _set(panel, "camera.pixel_count", 300, 280)
    assert state.design.camera.pixel_count == (300, 280)
    _set(panel, "relay.field_stop_diameter_mm", 0.0)  # the minimum reads "none"
    assert state.design.relay.field_stop_diameter_mm is None


def test_an_invalid_value_is_marked_with_the_reason_and_the_design_stays(panel, design):
    state = panel.state
    _set(panel, NA, 1.2)  # an air objective (n = 1) cannot have NA 1.2
    assert state.design == design  # the last valid design stays in force
    field, label = panel.inputs[NA], panel.error_labels[NA]
    assert field.property("invalid") is True
    assert "Numerical aperture 1.2 must be below immersion index 1" in label.text()  # the field labels
    assert "numerical_aperture" not in label.text() and "immersion_index" not in label.text()
    assert not label.isHidden()
    assert "border" in field.boxes[0].styleSheet() and "must be below" in field.boxes[0].toolTip()
    assert field.value() == pytest.approx(1.2)  # the user's value stays visible to be corrected
    # Another field edited meanwhile still applies on its own.
    _set(panel, "wavelength_nm", 700.0)
    assert state.design.wavelength_nm == 700.0 and NA in state.errors
    # Water immersion makes the waiting NA valid: both go into force together, the mark goes.
    _set(panel, "objective.immersion_index", 1.333)
    assert state.design.objective.numerical_aperture == pytest.approx(1.2)
    assert state.design.objective.immersion_index == pytest.approx(1.333)
    assert state.errors == {} and field.property("invalid") is False and label.isHidden()


def test_a_refused_value_is_dropped_when_the_document_is_replaced(panel, design):
    state = panel.state
    _set(panel, "depths.depth_step_um", 0.0)
    assert "Depth step must be a finite number > 0" in state.errors["depths.depth_step_um"]
    state.replace_design(design)
    assert panel.inputs["depths.depth_step_um"].value() == pytest.approx(10.0)
    assert panel.inputs["depths.depth_step_um"].property("invalid") is False


def test_state_changes_update_the_fields(panel, design):
    state = panel.state
    state.set_design(apply_changes(design, {"wavelength_nm": 690.0, "camera.read_noise_e": 2.0}))
    assert panel.inputs["wavelength_nm"].value() == pytest.approx(690.0)
    assert panel.inputs["camera.read_noise_e"].value() == pytest.approx(2.0)
    assert not state.errors  # programmatic updates do not echo back as edits


def test_accuracy_and_device_choices_reach_the_state(panel):
    panel.accuracy.textActivated.emit("standard")
    assert panel.state.design.accuracy.preset == "standard"
    panel.device.textActivated.emit("cpu")
    assert panel.state.device == "cpu"


def test_design_warnings_are_shown(panel):
    _set(panel, "camera.pixel_count", 200, 200)  # sub-images cut by the sensor edge: valid, with a warning
    assert panel.state.design.camera.pixel_count == (200, 200)
    assert "cut by the edge" in panel.warning_label.text() and not panel.warning_label.isHidden()


def test_a_conventional_design_disables_the_fourier_lens(qtbot):
    state = StudioState(load_preset("lfm_10x_na03"))
    panel = ParameterPanel(state)
    qtbot.addWidget(panel)
    assert not panel.inputs["relay.focal_length_mm"].isEnabled()
    assert panel.inputs["mla_to_camera_distance_mm"].isEnabled()
    panel.disconnect_state()


def test_greyed_fields_show_the_new_design_not_the_previous_one(qtbot):
    """Fourier -> conventional: the greyed relay fields show the conventional design's (absent) relay,
    as on a fresh launch, not the Fourier design's 75 mm and 2.66 mm."""
    conventional = load_preset("lfm_10x_na03")
    fresh = ParameterPanel(StudioState(conventional))
    qtbot.addWidget(fresh)
    state = StudioState(load_preset("flfm_guo2019"))
    panel = ParameterPanel(state)
    qtbot.addWidget(panel)
    state.set_design(conventional)
    for path in ("relay.focal_length_mm", "relay.field_stop_diameter_mm"):
        shown = [box.text() for box in panel.inputs[path].boxes]
        assert shown == [box.text() for box in fresh.inputs[path].boxes], path
    assert panel.inputs["relay.field_stop_diameter_mm"].boxes[0].text() == "none"
    assert "75" not in panel.inputs["relay.focal_length_mm"].boxes[0].text()
    for p in (fresh, panel):
        p.disconnect_state()


def test_text_that_is_no_number_is_refused_in_place_and_waits_to_be_corrected(panel, design):
    state = panel.state
    field, label = panel.inputs["objective.magnification"], panel.error_labels["objective.magnification"]
    _set(panel, "objective.magnification", "1e308")  # never read as 1308
    assert state.design == design and "Magnification 1e+308 is out of range" in label.text()
    assert not label.isHidden() and field.boxes[0].text() == "1e308" and field.property("invalid") is True
    _set(panel, "camera.read_noise_e", "0,5")  # another field applies meanwhile; the refused text stays
    assert state.design.camera.read_noise_e == 0.5 and field.boxes[0].text() == "1e308"
    assert state.design.objective.magnification == design.objective.magnification
    _set(panel, "objective.magnification", "25")
    assert state.design.objective.magnification == 25.0 and state.errors == {} and label.isHidden()
    _set(panel, "depths.depth_step_um", "-2")  # out of range: not turned into 2
    assert state.design.depths.depth_step_um == design.depths.depth_step_um
    state.replace_design(design)  # a new document drops the refused text
    assert panel.inputs["depths.depth_step_um"].boxes[0].text() == "10 µm" and not state.errors


def test_volume_grid_settings_are_edited_per_kind(panel, design):
    # Fourier design: volume voxels per pixel (odd); the conventional-only field does not apply.
    state = panel.state
    assert panel.inputs["accuracy.volume_oversampling"].value() == 1
    _set(panel, "accuracy.volume_oversampling", 3)
    assert state.design.accuracy.volume_oversampling == 3 and state.errors == {}
    _set(panel, "accuracy.volume_oversampling", 2)  # even: refused with the reason, design stays
    assert state.design.accuracy.volume_oversampling == 3
    assert "Volume voxels per pixel must be 1, 3, 5 or 7" in state.errors["accuracy.volume_oversampling"]


def test_a_field_shows_only_its_own_reason_while_another_field_is_refused(panel, design):
    state = panel.state
    _set(panel, "depths.depth_step_um", 0.0)  # refused, waits to be corrected
    _set(panel, "camera.quantum_efficiency", 1.5)  # refused too: together and alone
    qe, step = panel.error_labels["camera.quantum_efficiency"], panel.error_labels["depths.depth_step_um"]
    assert "Quantum efficiency must be in (0, 1]" in qe.text()
    assert "Depth step" not in qe.text() and "Depth step" not in state.errors["camera.quantum_efficiency"]
    assert "Depth step must be a finite number > 0" in step.text() and "uantum" not in step.text()
    assert state.design == design


@pytest.mark.parametrize("preset", ["lfm_10x_na03", "xlfm_cong2017"])
def test_the_panel_never_scrolls_sideways_at_its_minimum_width(qtbot, preset):
    """A fixed 340 px minimum left the conventional preset's fields 1 px too wide: a horizontal scroll
    bar under the panel. Its minimum now holds the widest field beside the vertical scroll bar."""
    state = StudioState(load_preset(preset))
    panel = ParameterPanel(state)
    qtbot.addWidget(panel)
    panel.resize(panel.minimumWidth(), 500)  # short: the vertical scroll bar shows
    panel.show()
    qtbot.waitExposed(panel)
    assert panel.verticalScrollBar().isVisible()
    assert panel.horizontalScrollBar().maximum() == 0
    panel.disconnect_state()
