"""The file dialogs' shared form (ui/path_form.py): the picker buttons fill their field and move the
next picker to that folder, a cancelled picker changes nothing, and OK keeps the dialog open and
says what is missing until the form is complete. Pickers are replaced by stand-ins (no native dialog)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from qtpy.QtWidgets import QFileDialog, QPushButton

from lfm_studio.ui.path_form import path_of, start_folder
from lfm_studio.ui.raw_frame_dialog import RawFrameDialog
from lfm_studio.ui.video_dialog import VideoDialog


def _buttons(row):
    return {b.text(): b for b in row.findChildren(QPushButton)}


def test_pickers_fill_their_field_and_the_next_one_opens_in_that_folder(qtbot, monkeypatch, tmp_path):
    asked = []

    def open_file(parent, title, folder, filter_=""):
        asked.append(("open", title, folder))
        return str(tmp_path / "frames" / "a.tif"), filter_

    def save_file(parent, title, folder, filter_="", options=None):
        asked.append(("save", title, folder, options))
        return str(tmp_path / "out" / "run"), filter_

    monkeypatch.setattr(QFileDialog, "getOpenFileName", staticmethod(open_file))
    monkeypatch.setattr(QFileDialog, "getSaveFileName", staticmethod(save_file))
    monkeypatch.setattr(QFileDialog, "getExistingDirectory", staticmethod(lambda *a, **k: ""))  # cancelled
    dialog = VideoDialog(folder=str(tmp_path))
    qtbot.addWidget(dialog)
    frames_row = dialog.frames_edit.parentWidget()
    _buttons(frames_row)["File…"].click()
    assert dialog.frames_edit.text() == str(tmp_path / "frames" / "a.tif")
    assert dialog.folder == str(tmp_path / "frames") and asked[0][2] == str(tmp_path)
    _buttons(frames_row)["Folder…"].click()  # cancelled: nothing changes
    assert dialog.frames() == tmp_path / "frames" / "a.tif" and dialog.folder == str(tmp_path / "frames")
    _buttons(dialog.output_edit.parentWidget())["Browse…"].click()
    assert asked[1][2] == str(tmp_path / "frames")  # opened where the last path was chosen
    assert asked[1][3] == QFileDialog.Option.DontConfirmOverwrite  # the studio asks before replacing a store
    assert dialog.output() == tmp_path / "out" / "run.ome.zarr" and dialog.folder == str(tmp_path / "out")

    raw = RawFrameDialog(folder=str(tmp_path))
    qtbot.addWidget(raw)
    _buttons(raw.raw_edit.parentWidget())["Browse…"].click()
    assert path_of(raw.raw_edit) == tmp_path / "frames" / "a.tif" and raw.folder == str(tmp_path / "frames")
    raw.make_new.setChecked(True)
    _buttons(raw.save_edit.parentWidget())["Browse…"].click()  # a file to write: the save picker
    assert asked[-1][:3] == ("save", "Save calibration as", str(tmp_path / "frames"))
    assert path_of(raw.save_edit) == tmp_path / "out" / "run"


def test_ok_says_what_is_missing_and_stays_open_until_the_form_is_complete(qtbot, tmp_path):
    raw_file = tmp_path / "raw.tif"
    raw_file.write_bytes(b"")
    dialog = RawFrameDialog(folder=str(tmp_path))
    qtbot.addWidget(dialog)
    dialog.show()
    dialog.ok_button.click()
    assert dialog.error_label.text() == "Raw camera frame: choose a file." and dialog.isVisible()
    dialog.raw_edit.setText(str(raw_file))
    dialog.calibration_edit.setText(str(tmp_path / "missing.json"))
    dialog.ok_button.click()
    assert "missing.json does not exist" in dialog.error_label.text() and dialog.isVisible()
    dialog.calibration_edit.setText(str(raw_file))
    dialog.ok_button.click()
    assert not dialog.isVisible() and dialog.result() == dialog.DialogCode.Accepted
    assert path_of(dialog.raw_edit) == raw_file


def test_pickers_start_in_the_folder_of_the_design_file_else_home(tmp_path):
    assert start_folder(SimpleNamespace(file_path=tmp_path / "d.json")) == str(tmp_path)
    assert start_folder(SimpleNamespace(file_path=None)) == str(Path.home())
