"""What the studio's file dialogs share (File > Open raw light field…, File > Reconstruct light-field video…).

:class:`PathFormDialog` is a dialog of path fields: each field is a line edit with its picker
buttons on one row (:meth:`~PathFormDialog.path_row`), a chosen path fills the field and becomes
the folder the next picker opens in (:meth:`~PathFormDialog.chosen`), a red line says what is
missing, and OK closes the dialog only when :meth:`~PathFormDialog.problem` finds nothing
(otherwise the line says it and the dialog stays open). :func:`start_folder` is where the
pickers start: the folder of the studio's design file, else the home folder.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from qtpy.QtWidgets import (
    QDialog,
    QDialogButtonBox,
    QHBoxLayout,
    QLabel,
    QLayout,
    QLineEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

ERROR_STYLE = "QLabel { color: #ff6b6b; }"


def start_folder(state: Any) -> str:
    """The folder a file dialog opens in: that of the studio's design file (``state.file_path``),
    else the home folder."""
    return str(state.file_path.parent) if state.file_path is not None else str(Path.home())


def path_of(edit: QLineEdit) -> Path | None:
    """The path typed in ``edit`` (``~`` expanded), or None when it is empty."""
    text = edit.text().strip()
    return Path(text).expanduser() if text else None


class PathFormDialog(QDialog):
    """A dialog of path fields that accepts only a complete form.

    Attributes
    ----------
    folder : where the next picker opens (the folder of the last chosen path).
    error_label : says what :meth:`problem` found when OK was pressed.
    ok_button : the OK button (after :meth:`lay_out`).
    """

    def __init__(self, parent: QWidget | None, *, title: str, folder: str = "") -> None:
        super().__init__(parent)
        self.setWindowTitle(title)
        self.folder = folder
        self.error_label = QLabel(self)
        self.error_label.setStyleSheet(ERROR_STYLE)
        self.error_label.setWordWrap(True)
        self.ok_button: QPushButton | None = None

    def path_row(self, edit: QLineEdit, *buttons: tuple[str, Callable[[], None]]) -> QWidget:
        """``edit`` and one push button per ``(text, slot)`` on one row (the field of a form)."""
        row = QWidget(self)
        layout = QHBoxLayout(row)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(edit, 1)
        for text, slot in buttons:
            button = QPushButton(text, row)
            button.clicked.connect(slot)
            layout.addWidget(button)
        return row

    def chosen(self, edit: QLineEdit, path: str) -> None:
        """A picker returned ``path`` (empty: cancelled, nothing changes): put it in ``edit`` and
        open the next picker in its folder."""
        if path:
            edit.setText(path)
            self.folder = str(Path(path).parent)

    def lay_out(self, form: QLayout, *below: QWidget) -> None:
        """The dialog's layout: ``form``, the ``below`` widgets, the error line, then OK / Cancel."""
        buttons = QDialogButtonBox(
            QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel
        )
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        self.ok_button = buttons.button(QDialogButtonBox.StandardButton.Ok)
        layout = QVBoxLayout(self)
        layout.addLayout(form)
        for widget in below:
            layout.addWidget(widget)
        layout.addWidget(self.error_label)
        layout.addWidget(buttons)

    def problem(self) -> str | None:
        """What is missing or wrong (named with its field and the fix), or None: the subclass's checks."""
        return None

    def accept(self) -> None:
        """Close only when :meth:`problem` finds nothing; otherwise say what it found."""
        problem = self.problem()
        if problem is not None:
            self.error_label.setText(problem)
            return
        super().accept()
