"""Refused values on screen: the input Save does not write and closing the document would lose.

A parameter field, or the MLA editor, that holds a refused value shows input that is not in
the design in force (:attr:`~lfm_studio.ui.state.StudioState.errors`: path -> reason). While
any is on screen the document has unsaved input
(:attr:`~lfm_studio.ui.state.StudioState.unsaved_input`), even right after a save. Save and
Save as… ask first (:func:`confirm_save_refused`); closing or replacing the document asks too
(:meth:`~lfm_studio.ui.file_menu.FileActions.confirm_discard`, worded with :func:`refused_text`).

A model trained in the Train dock and not yet saved to a checkpoint is unsaved input the same way
(:attr:`~lfm_studio.ui.state.StudioState.unsaved_model`): closing or replacing the document asks
first, worded with :func:`unsaved_model_text`.
"""

from __future__ import annotations

from collections.abc import Iterable

from qtpy.QtWidgets import QMessageBox, QWidget

from lfm_studio.ui.controllers import MLAEditorBinding
from lfm_studio.ui.parameter_fields import FIELDS

SAVE_ANYWAY = "Save the last valid design anyway"
_LABELS = {spec.path: spec.label for spec in FIELDS} | {MLAEditorBinding.ERROR_KEY: "MLA layout"}
_ORDER = {path: index for index, path in enumerate(_LABELS)}  # the window's order: panel, then editor


def refused_labels(paths: Iterable[str]) -> tuple[str, ...]:
    """What the user reads for each refused field path (in the window's order; unknown paths as they are)."""
    ordered = sorted(set(paths), key=lambda p: (_ORDER.get(p, len(_ORDER)), p))
    return tuple(_LABELS.get(path, path) for path in ordered)


def refused_text(paths: Iterable[str], fate: str) -> str:
    """One sentence: how many fields show refused values, what happens to them (``fate``) and which.

    E.g. ``"2 fields show refused values that will not be saved: Numerical aperture, MLA layout."``
    """
    labels = refused_labels(paths)
    if len(labels) == 1:
        return f"1 field shows a refused value that {fate}: {labels[0]}."
    return f"{len(labels)} fields show refused values that {fate}: {', '.join(labels)}."


def unsaved_model_text(what: str) -> str:
    """One sentence: the trained model ``what`` (e.g. ``"the trained unrolled-rl model (60 steps)"``)
    is only in memory and will be lost, and how to keep it."""
    return (
        f"{what[:1].upper()}{what[1:]} is not saved and will be lost. "
        "Fix: to keep it, cancel and press Save checkpoint… in the Train dock."
    )


def confirm_save_refused(parent: QWidget | None, paths: Iterable[str]) -> bool:
    """True when nothing refused is on screen, or the user chose to save the last valid design anyway."""
    paths = tuple(paths)
    if not paths:
        return True
    box = QMessageBox(parent)
    box.setIcon(QMessageBox.Icon.Warning)
    box.setWindowTitle("Refused values on screen")
    box.setText(refused_text(paths, "will not be saved"))
    box.setInformativeText(
        "Saving writes the last valid design, which differs from what these fields show. "
        "Fix: correct the values (each field says why it was refused), or save anyway."
    )
    save = box.addButton(SAVE_ANYWAY, QMessageBox.ButtonRole.AcceptRole)
    box.setDefaultButton(box.addButton(QMessageBox.StandardButton.Cancel))
    box.exec()
    return box.clickedButton() is save
