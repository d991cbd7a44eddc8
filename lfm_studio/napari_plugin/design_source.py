"""Where a plugin widget's design comes from: a bundled preset or a design file.

One row, shared by the Simulate, Calibrate and MLA-editor docks: a preset list and a file
button. A chosen design goes to the widget's ``on_design(design, label)``; a design that cannot
be read or is refused gives an error notification and changes nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from qtpy.QtWidgets import QComboBox, QFileDialog, QHBoxLayout, QPushButton, QWidget

from lfm_studio.engine.design import Design, list_presets, load_design, load_preset
from lfm_studio.napari_plugin.notify import design_or_report


class DesignSource(QWidget):
    """A preset list and a design-file button; ``on_design(design, label)`` receives each choice.

    ``refusal``: the verb of the error notification, e.g. ``"use"`` gives "Cannot use preset X: ...".
    """

    def __init__(
        self,
        on_design: Callable[[Design, str], None],
        *,
        refusal: str = "use",
        file_button: str = "Design file...",
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self._on_design, self._refusal = on_design, refusal
        self.preset = QComboBox()
        self.preset.addItems(list_presets())
        self.file_button = QPushButton(file_button)
        self.row = QHBoxLayout(self)
        self.row.setContentsMargins(0, 0, 0, 0)
        self.row.addWidget(self.preset, 1)
        self.row.addWidget(self.file_button)
        self.preset.currentTextChanged.connect(self.set_preset)
        self.file_button.clicked.connect(self._browse)

    def choose_first(self) -> None:
        """Hand over the preset shown in the list (a new widget starts on it)."""
        if self.preset.count():
            self.set_preset(self.preset.currentText())

    def set_preset(self, name: str) -> bool:
        """Use the bundled preset ``name``; False (with an error notification) if it cannot be read."""
        return self._load(load_preset, name, f"preset {name}")

    def load_design_file(self, path: str | Path) -> bool:
        """Use the design file ``path``; False (with an error notification) if it cannot be read."""
        return self._load(load_design, Path(path), Path(path).name)

    def _load(self, loader: Callable[[object], Design], argument: object, label: str) -> bool:
        design = design_or_report(loader, argument, f"Cannot {self._refusal} {label}")
        if design is not None:
            self._on_design(design, label)
        return design is not None

    def _browse(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Open a design file", "", "Design files (*.json)")
        if path:
            self.load_design_file(path)
