"""Failures the user did not cause by typing get a dialog they cannot miss, not only a status-bar line.

:func:`show_failure` opens a window-modal, non-blocking message box (``open()``, so a
job's result handler never waits inside a nested event loop). :class:`JobFailureNotices`
shows one for each failed background job (PSF, image, reconstruction, metrics) of the
current generation. :func:`write_error_text` words a failed write for the user: it names
the user's file, never the temporary file the atomic writer uses, and gives the fix.
"""

from __future__ import annotations

import errno
from collections.abc import Iterable
from pathlib import Path

from qtpy.QtCore import QObject, Qt
from qtpy.QtWidgets import QMessageBox, QWidget

from lfm_studio.ui.results import JobStatus
from lfm_studio.ui.state import StudioState
from lfm_studio.widgets.numeric_text import shown_units_in

JOB_WHAT = {
    "psf": "The PSF computation",
    "image": "The light-field image simulation",
    "reconstruction": "The reconstruction",
    "metrics": "The design metrics measurement",
}
_READ_ONLY = {errno.EACCES: "you have no permission to write there", errno.EPERM: "you have no permission to write there",
              errno.EROFS: "the folder is on a read-only file system"}  # fmt: skip


def show_failure(parent: QWidget | None, title: str, text: str, details: str = "") -> QMessageBox:
    """A warning box over ``parent`` with ``text`` (and ``details`` behind "Show Details…"); returns it open.

    The engine's unit "um" in ``text`` reads "µm", as everywhere in the studio (:func:`shown_units_in`;
    the details, a traceback, stay as they were)."""
    box = QMessageBox(
        QMessageBox.Icon.Warning, title, shown_units_in(text), QMessageBox.StandardButton.Ok, parent
    )
    box.setAttribute(Qt.WidgetAttribute.WA_DeleteOnClose)
    box.setWindowModality(Qt.WindowModality.WindowModal)
    if details:
        box.setDetailedText(details)
    box.open()
    return box


def write_error_text(path: str | Path, error: OSError) -> str:
    """Why ``path`` could not be written, naming ``path`` (not a temporary file) and the fix."""
    target = Path(path)
    folder = target.parent
    if error.errno in _READ_ONLY:
        return (
            f"Cannot write {target.name} in {folder}: {_READ_ONLY[error.errno]}. Fix: choose another folder "
            f"(Save as… / Export to a folder of yours), or make {folder} writable."
        )
    if error.errno == errno.ENOSPC:
        return f"Cannot write {target}: the disk is full. Fix: free some space, or choose another disk."
    reason = (error.strerror or str(error)).rstrip(".")
    if error.filename is not None and Path(error.filename) not in (target, folder):  # e.g. the .tmp file
        reason = reason.replace(str(error.filename), str(target))
    fix = "" if "Fix:" in reason else " Fix: choose another file or folder."
    return f"Cannot write {target}: {reason}.{fix}"


class JobFailureNotices(QObject):
    """A dialog for each failed job of ``names`` (once per job generation), parented to ``window``.

    ``last`` is the most recent dialog (None before any failure).
    """

    def __init__(self, state: StudioState, window: QWidget, names: Iterable[str] = tuple(JOB_WHAT)) -> None:
        super().__init__(window)
        self.state, self.window, self.names = state, window, frozenset(names)
        self.last: QMessageBox | None = None
        self._shown: set[tuple[str, int]] = set()
        state.job_changed.connect(self._on_job)

    def disconnect_state(self) -> None:
        self.state.job_changed.disconnect(self._on_job)

    def _on_job(self, status: JobStatus) -> None:
        key = (status.name, status.generation)
        if status.state != "failed" or status.name not in self.names or key in self._shown:
            return
        self._shown.add(key)
        error = status.message.removeprefix("failed: ")
        what = JOB_WHAT.get(status.name, f"The {status.name} job")
        self.last = show_failure(
            self.window,
            f"{what.removeprefix('The ')} failed",
            f"{what} stopped with an error:\n\n{error}\n\nWhat is on screen is the last result computed "
            "before it, if any. Fix the cause (often a design value) and it runs again.",
        )
