"""Failures the user did not cause by typing: a dialog that cannot be missed, the user's file named
with the fix (never the atomic writer's .tmp file), a truncated TIFF called truncated."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest
import torch
from qtpy.QtWidgets import QMessageBox, QWidget

from lfm_studio.ui.failure_notices import JobFailureNotices, write_error_text
from lfm_studio.ui.results import ImageResult, JobStatus
from lfm_studio.ui.state import StudioState
from lfm_studio.widgets.jobs import JobRunner
from tests.ui.standins import small_fourier_design
from tests.ui.test_file_menu import Dialogs, design, menu  # noqa: F401 - the File menu's fixtures


@pytest.fixture
def read_only_folder(tmp_path):
    """A folder this process cannot write into (root ignores permission bits: then /sys)."""
    folder = tmp_path / "read_only"
    folder.mkdir()
    folder.chmod(0o555)
    for candidate in (folder, Path("/sys")):
        try:
            (candidate / ".probe").touch()
        except OSError:
            yield candidate
            break
        (candidate / ".probe").unlink()
    else:
        pytest.skip("no read-only folder available here")
    folder.chmod(0o755)


@pytest.mark.parametrize(
    ("error", "expected"),
    [
        (PermissionError(errno.EACCES, "Permission denied", "/data/.a.json.x1y2.tmp"), "no permission to write"),
        (OSError(errno.EROFS, "Read-only file system", "/data/.a.json.x1y2.tmp"), "read-only file system"),
        (OSError(errno.ENOSPC, "No space left on device", "/data/.a.json.x1y2.tmp"), "the disk is full"),
        (OSError(errno.EIO, "Input/output error: /data/.a.json.x1y2.tmp", "/data/.a.json.x1y2.tmp"), "Input/output"),
    ],
)  # fmt: skip
def test_write_errors_name_the_users_file_and_the_fix(error, expected):
    text = write_error_text("/data/a.json", error)
    assert "a.json" in text and expected in text and "Fix:" in text
    assert ".tmp" not in text and "x1y2" not in text


def test_saving_into_a_read_only_folder_names_the_file_and_the_fix(menu, read_only_folder):  # noqa: F811
    menu.dialogs.save_path = read_only_folder / "zebrafish.json"
    assert not menu.actions.save_as()
    (text,) = menu.dialogs.warnings
    assert (
        f"Cannot write zebrafish.json in {read_only_folder}" in text and "Fix: choose another folder" in text
    )
    assert ".tmp" not in text and not (read_only_folder / "zebrafish.json").exists()
    assert menu.state.file_path is None  # nothing was saved


def test_a_failed_export_gets_a_dialog_naming_the_file(menu, qtbot, read_only_folder):  # noqa: F811
    counts = torch.arange(12.0).reshape(3, 4)
    menu.state.set_image(
        ImageResult(counts, counts, torch.rand(2, 3, 3), (2e-6, 1e-6, 1e-6), 6.5e-6, None, {})
    )
    menu.dialogs.save_path = read_only_folder / "light_field.tif"
    assert menu.actions.last_failure is None
    menu.actions.export_image_action.trigger()
    qtbot.waitUntil(lambda: menu.state.job("export").state == "failed", timeout=10_000)
    box = menu.actions.last_failure
    assert isinstance(box, QMessageBox) and box.isVisible() and box.windowTitle() == "Export failed"
    assert "light_field.tif" in box.text() and "Fix:" in box.text() and ".tmp" not in box.text()
    assert "Traceback" in box.detailedText()
    box.close()


def _boom(ctx, message):
    raise RuntimeError(message)


def test_a_failed_job_gets_one_dialog_per_run(qtbot):
    window = QWidget()
    qtbot.addWidget(window)
    state = StudioState(small_fourier_design())
    runner = JobRunner(window)
    runner.status_changed.connect(state.set_job)  # what the controller does
    notices = JobFailureNotices(state, window)
    runner.submit("psf", _boom, "not enough memory for 40 depths")
    qtbot.waitUntil(lambda: state.job("psf").state == "failed", timeout=10_000)
    box = notices.last
    assert box is not None and box.isVisible() and box.windowTitle() == "PSF computation failed"
    assert "not enough memory for 40 depths" in box.text()
    state.set_job(JobStatus("psf", "failed", 0, 0, "failed: again", state.job("psf").generation))
    assert notices.last is box  # the same run: no second dialog
    runner.submit("export", _boom, "disk gone")  # exports have their own dialog, naming the file
    qtbot.waitUntil(lambda: state.job("export").state == "failed", timeout=10_000)
    assert notices.last is box
    box.close()
    notices.disconnect_state()
    runner.shutdown()


def test_a_truncated_phantom_tiff_is_reported_as_truncated(tmp_path):
    from lfm_studio.engine.io import write_volume
    from lfm_studio.engine.phantoms import from_tiff

    path = tmp_path / "phantom.tif"
    write_volume(path, torch.rand(5, 93, 93), voxel_size=(2e-6, 1e-6, 1e-6))
    assert tuple(from_tiff(path).data.shape) == (5, 93, 93)
    size = path.stat().st_size
    with open(path, "r+b") as handle:
        handle.truncate(size // 3)  # an interrupted copy
    with pytest.raises(ValueError, match="is truncated: its ImageJ header announces 5 images but only 1"):
        from_tiff(path, normalize=True)
    assert os.path.getsize(path) == size // 3


def test_a_failure_dialog_writes_the_engines_um_as_micrometres(qtbot):
    """Dialogs built from an engine message directly (open file, raw frame, video, docks) read µm,
    as the studio's own text does; words, keys and paths keep their letters; the details stay raw."""
    from lfm_studio.ui.failure_notices import show_failure

    parent = QWidget()
    qtbot.addWidget(parent)
    box = show_failure(
        parent, "Cannot open", "depth_step_um 0 um must be > 0 (maximum 5 um^2)", details="at 3 um"
    )
    assert box.text() == "depth_step_um 0 µm must be > 0 (maximum 5 µm²)"
    assert box.detailedText() == "at 3 um"
    box.close()
