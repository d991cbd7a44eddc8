"""The File menu: save/open round trip, no overwrite without confirmation, unsaved-changes prompt,
recent files (in a temporary QSettings file), TIFF export. Dialogs are monkeypatched."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import pytest
from qtpy.QtCore import QSettings, Qt
from qtpy.QtTest import QTest
from qtpy.QtWidgets import QFileDialog, QMainWindow, QMessageBox

from lfm_studio.engine.design import load_design
from lfm_studio.ui import pipeline
from lfm_studio.ui.edits import apply_changes
from lfm_studio.ui.file_menu import RECENT_KEY, FileActions
from lfm_studio.ui.parameter_panel import ParameterPanel
from lfm_studio.ui.refused_input import SAVE_ANYWAY
from lfm_studio.ui.state import StudioState
from lfm_studio.widgets.jobs import JobRunner
from tests.ui.standins import small_fourier_design

Button = QMessageBox.StandardButton


@pytest.fixture(scope="module")
def design():
    return small_fourier_design()


class Dialogs:
    """Scripted answers for QFileDialog / QMessageBox, recording the questions asked."""

    def __init__(self, monkeypatch):
        self.save_path = self.open_path = ""
        self.answers: list[Button] = []
        self.questions: list[str] = []
        self.warnings: list[str] = []
        self.clicks: list[str] = []  # the button (its text) to press in each message box run with exec()
        self.boxes: list[tuple[str, tuple[str, ...]]] = []  # (text, button texts) of each one
        monkeypatch.setattr(QFileDialog, "getSaveFileName", self._save)
        monkeypatch.setattr(QFileDialog, "getOpenFileName", self._open)
        monkeypatch.setattr(QMessageBox, "question", self._question)
        monkeypatch.setattr(QMessageBox, "warning", self._warning)
        monkeypatch.setattr(QMessageBox, "exec", lambda box: self._exec(box))  # bound to the box

    def _save(self, *args, **kwargs):
        return str(self.save_path), "Design files (*.json)"

    def _open(self, *args, **kwargs):
        return str(self.open_path), "Design files (*.json)"

    def _question(self, parent, title, text, *args, **kwargs):
        self.questions.append(text)
        return self.answers.pop(0)

    def _warning(self, parent, title, text, *args, **kwargs):
        self.warnings.append(text)
        return Button.Ok

    def _exec(self, box):
        buttons = {button.text().replace("&", ""): button for button in box.buttons()}
        self.boxes.append((box.text(), tuple(buttons)))
        buttons[self.clicks.pop(0)].click()
        return 0


@pytest.fixture
def menu(qtbot, design, tmp_path, monkeypatch):
    window = QMainWindow()
    qtbot.addWidget(window)
    state = StudioState(design)
    runner = JobRunner(window)
    runner.status_changed.connect(state.set_job)  # what the controller does in the studio
    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    actions = FileActions(state, window, runner, settings=settings)
    actions.populate(window.menuBar().addMenu("&File"))
    yield SimpleNamespace(
        state=state, actions=actions, dialogs=Dialogs(monkeypatch), settings=settings, runner=runner
    )
    actions.disconnect_state()
    runner.shutdown()


def test_save_as_then_open_round_trip(menu, design, tmp_path):
    state, actions, dialogs = menu.state, menu.actions, menu.dialogs
    edited = apply_changes(design, {"wavelength_nm": 690.0})
    state.set_design(edited)
    dialogs.save_path = tmp_path / "mine.json"
    actions.save_as_action.trigger()
    assert load_design(tmp_path / "mine.json") == edited
    assert state.file_path == (tmp_path / "mine.json").resolve() and not state.dirty
    assert dialogs.questions == []  # a new file: nothing to confirm
    state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))  # unsaved edit
    dialogs.open_path, dialogs.answers = tmp_path / "mine.json", [Button.Discard]
    actions.open_action.trigger()
    assert "unsaved changes" in dialogs.questions[0]
    assert state.design == edited and not state.dirty
    # Save goes to the open document without a dialog.
    state.set_design(apply_changes(design, {"wavelength_nm": 695.0}))
    dialogs.save_path = ""  # a dialog would cancel
    assert actions.save()
    assert load_design(tmp_path / "mine.json").wavelength_nm == 695.0


def test_an_existing_file_is_never_replaced_without_confirmation(menu, tmp_path):
    target = tmp_path / "precious.json"
    target.write_text("keep me")
    dialogs = menu.dialogs
    dialogs.save_path, dialogs.answers = target, [Button.No]
    assert not menu.actions.save_as()
    assert target.read_text() == "keep me" and "already exists" in dialogs.questions[-1]
    dialogs.answers = [Button.Yes]
    assert menu.actions.save_as()
    assert load_design(target) == menu.state.design


def test_unsaved_changes_prompt(menu, design, tmp_path):
    state, actions, dialogs = menu.state, menu.actions, menu.dialogs
    state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))
    dialogs.answers = [Button.Cancel]
    assert not actions.new_from_preset("xlfm_cong2017")
    assert state.design.wavelength_nm == 700.0 and state.dirty
    dialogs.answers, dialogs.save_path = [Button.Save], tmp_path / "saved_first.json"
    assert actions.new_from_preset("xlfm_cong2017")
    assert load_design(tmp_path / "saved_first.json").wavelength_nm == 700.0
    assert state.design.name.startswith("XLFM") and not state.dirty and state.file_path is None
    assert actions.confirm_discard() and len(dialogs.questions) == 2  # clean: no question


def test_an_unsaved_trained_model_asks_before_the_document_is_replaced(menu, design, tmp_path):
    state, actions, dialogs = menu.state, menu.actions, menu.dialogs
    state.set_unsaved_model("the trained unrolled-rl model (60 steps)")
    assert state.unsaved_input and not state.dirty
    dialogs.answers = [Button.Cancel]
    assert not actions.new_from_preset("xlfm_cong2017")
    assert dialogs.questions[-1] == (
        "The trained unrolled-rl model (60 steps) is not saved and will be lost. Fix: to keep it, cancel "
        "and press Save checkpoint… in the Train dock. Discard it?"
    )
    assert state.design == design and state.unsaved_model is not None
    # With unsaved design changes too, the one question names both.
    state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))
    dialogs.answers = [Button.Discard]
    assert actions.new_from_preset("xlfm_cong2017")
    assert (
        "unsaved changes" in dialogs.questions[-1] and "unrolled-rl model (60 steps)" in dialogs.questions[-1]
    )
    assert state.unsaved_model is None and not state.unsaved_input  # a new document: the model went with it
    assert actions.confirm_discard() and len(dialogs.questions) == 2


def test_save_with_a_refused_value_on_screen_asks_and_cancel_writes_nothing(menu, qtbot, design, tmp_path):
    state, actions, dialogs = menu.state, menu.actions, menu.dialogs
    panel = ParameterPanel(state)
    qtbot.addWidget(panel)
    target = tmp_path / "mine.json"
    dialogs.save_path = target
    assert actions.save_as()  # nothing refused: no question
    assert dialogs.boxes == [] and not state.unsaved_input
    written = target.read_bytes()
    box = panel.inputs["objective.numerical_aperture"].boxes[0]
    box.setFocus()
    box.selectAll()
    QTest.keyClicks(box, "2.5")  # what the user does: refused (an air objective)
    QTest.keyClick(box, Qt.Key.Key_Return)
    assert "objective.numerical_aperture" in state.errors and state.design == design
    assert state.unsaved_input and not state.dirty  # the design is saved, the field is not
    dialogs.clicks = ["Cancel"]
    actions.save_action.trigger()
    text, buttons = dialogs.boxes[-1]
    assert text == "1 field shows a refused value that will not be saved: Numerical aperture."
    assert buttons == (SAVE_ANYWAY, "Cancel")
    assert target.read_bytes() == written
    dialogs.clicks, dialogs.save_path = ["Cancel"], tmp_path / "other.json"
    assert not actions.save_as()  # Save as asks too, before the file dialog
    assert not (tmp_path / "other.json").exists() and len(dialogs.boxes) == 2
    state.set_field_error("mla", "lenslet apertures must not overlap")  # the editor's refusal
    dialogs.clicks = [SAVE_ANYWAY]
    assert actions.save_as()
    assert dialogs.boxes[-1][0] == (
        "2 fields show refused values that will not be saved: Numerical aperture, MLA layout."
    )
    assert load_design(tmp_path / "other.json") == design  # the last valid design
    assert not state.dirty and state.unsaved_input  # the refused values are still not saved
    panel.disconnect_state()


def test_replacing_the_document_asks_about_refused_values_on_screen(menu, design):
    state, actions, dialogs = menu.state, menu.actions, menu.dialogs
    state.set_field_error(
        "objective.numerical_aperture", "numerical_aperture 2.5 must be below immersion_index 1"
    )
    dialogs.answers = [Button.Cancel]
    assert not actions.new_from_preset("xlfm_cong2017")
    assert dialogs.questions[-1] == (
        "1 field shows a refused value that will be lost: Numerical aperture. Discard it?"
    )
    assert state.design == design and state.errors
    state.set_design(apply_changes(design, {"wavelength_nm": 700.0}))  # and an unsaved change
    dialogs.answers = [Button.Discard]
    assert actions.new_from_preset("xlfm_cong2017")
    assert (
        "unsaved changes" in dialogs.questions[-1]
        and "will not be saved: Numerical aperture" in dialogs.questions[-1]
    )
    assert not state.unsaved_input and dialogs.boxes == []


def test_recent_files_persist_in_the_settings(menu, qtbot, tmp_path):
    menu.dialogs.save_path = tmp_path / "a.json"
    menu.actions.save_as()
    menu.settings.sync()
    stored = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat).value(RECENT_KEY)
    stored = [stored] if isinstance(stored, str) else stored
    assert stored == [str((tmp_path / "a.json").resolve())]
    assert [a.data() for a in menu.actions.recent_menu.actions()] == stored
    # A second window with the same settings lists it too.
    other, window = StudioState(menu.state.design), QMainWindow()
    qtbot.addWidget(window)
    again = FileActions(other, window, menu.runner, settings=menu.settings)
    assert other.recent_files == ((tmp_path / "a.json").resolve(),)
    again.disconnect_state()


def test_a_broken_file_is_reported_and_nothing_changes(menu, design, tmp_path):
    broken = tmp_path / "broken.json"
    broken.write_text("{ not json")
    assert not menu.actions.open_file(broken)
    assert "not valid JSON" in menu.dialogs.warnings[0]
    assert menu.state.design == design


def test_export_psf_stack_as_tiff(menu, qtbot, design, tmp_path):
    from lfm_studio.engine.io import read_psf_stack

    actions = menu.actions
    assert not actions.export_psf_action.isEnabled()
    ctx = SimpleNamespace(
        cancel=threading.Event(), progress=lambda *a: None, partial=None, check=lambda *a: None
    )
    menu.state.set_psf(pipeline.compute_psf(ctx, pipeline.PSFRequest.for_design(design), None))
    assert actions.export_psf_action.isEnabled()
    menu.dialogs.save_path = tmp_path / "psf.tif"
    actions.export_psf_action.trigger()
    qtbot.waitUntil(lambda: menu.state.job("export").state == "done", timeout=60_000)
    stack = read_psf_stack(tmp_path / "psf.tif")
    assert stack.data.shape == (3, 256, 256) and stack.design == design


def test_export_image_and_reconstruction_as_tiff(menu, qtbot, tmp_path):
    import torch

    from lfm_studio.engine.io import read_image, read_volume
    from lfm_studio.ui.results import ImageResult, ReconstructionResult

    actions, state, dialogs = menu.actions, menu.state, menu.dialogs
    assert (
        not actions.export_image_action.isEnabled() and not actions.export_reconstruction_action.isEnabled()
    )
    counts = torch.arange(12.0).reshape(3, 4)
    volume = torch.rand(2, 3, 3)
    state.set_image(
        ImageResult(counts, counts, volume, (2e-6, 1e-6, 1e-6), 6.5e-6, None, {"phantom": "beads"})
    )
    state.set_reconstruction(ReconstructionResult(volume, (2e-6, 1e-6, 1e-6), 4, psnr=30.0, ssim=0.9))
    dialogs.save_path = tmp_path / "lf.tif"
    actions.export_image_action.trigger()
    qtbot.waitUntil(lambda: state.job("export").state == "done", timeout=60_000)
    image = read_image(tmp_path / "lf.tif")
    assert torch.equal(image.data, counts) and image.pixel_size == pytest.approx(6.5e-6)
    dialogs.save_path = tmp_path / "lf.tif"  # exists now: refused without confirmation
    dialogs.answers = [Button.No]
    assert not actions.export_reconstruction()
    dialogs.save_path = tmp_path / "volume.tif"
    actions.export_reconstruction_action.trigger()
    qtbot.waitUntil(
        lambda: (tmp_path / "volume.tif").exists() and state.job("export").state == "done", timeout=60_000
    )
    saved = read_volume(tmp_path / "volume.tif")
    assert torch.allclose(saved.data, volume) and saved.voxel_size == pytest.approx((2e-6, 1e-6, 1e-6))
