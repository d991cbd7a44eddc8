"""Keyboard shortcuts of the MLA editor, as an event filter that wins over window-wide shortcuts.

Filtered widgets accept the ``ShortcutOverride`` of the editor's keys, so an
application menu that also binds Ctrl+Z does not steal (or make ambiguous) the key
while the editor has focus; the key press then becomes ``triggered(action)``.
Text fields (spin boxes, table cell editors) are not filtered and keep their own
Ctrl+Z and Delete.
"""

from __future__ import annotations

from qtpy.QtCore import QEvent, QObject, Qt, Signal


def key_action(event) -> str | None:
    """The editor action of a key event: "undo", "redo", "delete", "select_all", "escape" or None."""
    mods, key = event.modifiers(), event.key()
    ctrl = bool(mods & Qt.KeyboardModifier.ControlModifier)
    shift = bool(mods & Qt.KeyboardModifier.ShiftModifier)
    alt = bool(mods & Qt.KeyboardModifier.AltModifier)
    if ctrl and not alt and key == Qt.Key.Key_Z:
        return "redo" if shift else "undo"
    if ctrl and not (alt or shift) and key in (Qt.Key.Key_Y, Qt.Key.Key_A):
        return "redo" if key == Qt.Key.Key_Y else "select_all"
    if not (ctrl or alt) and key in (Qt.Key.Key_Delete, Qt.Key.Key_Backspace):
        return "delete"
    return "escape" if key == Qt.Key.Key_Escape else None


class EditorKeys(QObject):
    """Install on the editor and its views with ``widget.installEventFilter(keys)``."""

    triggered = Signal(str)

    def eventFilter(self, obj, event) -> bool:
        if event.type() in (QEvent.Type.ShortcutOverride, QEvent.Type.KeyPress):
            action = key_action(event)
            if action is not None:
                event.accept()
                if event.type() == QEvent.Type.KeyPress:
                    self.triggered.emit(action)
                return True
        return super().eventFilter(obj, event)
