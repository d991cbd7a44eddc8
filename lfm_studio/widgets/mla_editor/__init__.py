"""The MLA layout editor (:class:`MLAEditor`), one module per part.

Qt-free: :mod:`.model` (lenslet geometry and edits), :mod:`.session` (undo/redo, refusals),
:mod:`.symmetry`, :mod:`.presets`, :mod:`.checks`. Qt: :mod:`.editor` (the widget), :mod:`.canvas`,
:mod:`.sensor`, :mod:`.table`, :mod:`.controls`, :mod:`.views`, :mod:`.keys`, :mod:`.style`.
:class:`MLAEditor` is imported on first use, so the Qt-free modules load without Qt.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lfm_studio.widgets.mla_editor.editor import MLAEditor

__all__ = ["MLAEditor"]


def __getattr__(name: str) -> Any:
    if name == "MLAEditor":
        from lfm_studio.widgets.mla_editor.editor import MLAEditor

        return MLAEditor
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
