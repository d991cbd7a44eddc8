"""The MLA editor's table of lenslets: x, y, diameter Ø (µm), focal length f (mm); editable.

The headers are short (the editor's own Ø and f) with the full meaning in their tooltips, and no
column is narrower than its header: in a narrow dock the table scrolls rather than clip them.

The model never changes the list itself: an edit becomes ``editRequested(row, field,
text)`` and the editor validates and commits it (or refuses it with the reason),
then shows the new list with :meth:`LensletTableModel.set_lenslets`. Rows with an
issue are red, with the reasons as their tooltip.
"""

from __future__ import annotations

from collections.abc import Sequence

from qtpy.QtCore import QAbstractTableModel, QItemSelection, QItemSelectionModel, QModelIndex, Qt, Signal
from qtpy.QtGui import QColor
from qtpy.QtWidgets import QAbstractItemView, QHeaderView, QStyle, QTableView

from lfm_studio.engine.design import LensletSpec
from lfm_studio.widgets.mla_editor.model import FIELDS, value_of
from lfm_studio.widgets.mla_editor.style import ISSUE

HEADERS = ("x (µm)", "y (µm)", "Ø (µm)", "f (mm)")
HEADER_TIPS = (
    "x of the lenslet centre, µm from the optical axis",
    "y of the lenslet centre, µm from the optical axis",
    "Ø: aperture diameter, µm",
    "f: focal length, mm",
)


def _text(value: float) -> str:
    return f"{value:.10g}"


class LensletTableModel(QAbstractTableModel):
    """Rows are lenslets (vertical header: the lenslet index), columns the fields of :data:`FIELDS`."""

    editRequested = Signal(int, str, str)  # noqa: N815 - Qt signal names are camelCase

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self._lenslets: tuple[LensletSpec, ...] = ()
        self._issues: dict[int, list[str]] = {}

    def set_lenslets(self, lenslets: Sequence[LensletSpec]) -> None:
        """Show ``lenslets`` (only changed rows are repainted when the count is unchanged)."""
        lenslets = tuple(lenslets)
        if len(lenslets) != len(self._lenslets):
            self.beginResetModel()
            self._lenslets = lenslets
            self.endResetModel()
            return
        changed = [i for i, (a, b) in enumerate(zip(lenslets, self._lenslets, strict=True)) if a != b]
        self._lenslets = lenslets
        if changed:
            self.dataChanged.emit(self.index(min(changed), 0), self.index(max(changed), len(FIELDS) - 1))

    def set_issues(self, issues: dict[int, list[str]]) -> None:
        """Mark rows with reasons (red text, reasons as tooltip)."""
        if issues == self._issues:
            return
        self._issues = issues
        if self._lenslets:
            self.dataChanged.emit(self.index(0, 0), self.index(len(self._lenslets) - 1, len(FIELDS) - 1))

    def rowCount(self, parent=QModelIndex()) -> int:  # noqa: B008 - Qt's signature
        return 0 if parent.isValid() else len(self._lenslets)

    def columnCount(self, parent=QModelIndex()) -> int:  # noqa: B008
        return 0 if parent.isValid() else len(FIELDS)

    def headerData(self, section, orientation, role=Qt.ItemDataRole.DisplayRole):
        horizontal = orientation == Qt.Orientation.Horizontal and 0 <= section < len(HEADERS)
        if role == Qt.ItemDataRole.ToolTipRole and horizontal:
            return HEADER_TIPS[section]
        if role != Qt.ItemDataRole.DisplayRole:
            return None
        if orientation == Qt.Orientation.Horizontal:
            return HEADERS[section] if horizontal else None
        return str(section)

    def data(self, index, role=Qt.ItemDataRole.DisplayRole):
        if not index.isValid() or not 0 <= index.row() < len(self._lenslets):
            return None
        row, field = index.row(), FIELDS[index.column()]
        if role in (Qt.ItemDataRole.DisplayRole, Qt.ItemDataRole.EditRole):
            return _text(value_of(self._lenslets[row], field))
        if role == Qt.ItemDataRole.TextAlignmentRole:
            return int(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        issues = self._issues.get(row)
        if role == Qt.ItemDataRole.ForegroundRole and issues:
            return QColor(ISSUE)
        if role == Qt.ItemDataRole.ToolTipRole and issues:
            return "\n".join(f"lenslet {row} {t}" for t in issues)
        return None

    def flags(self, index):
        if not index.isValid():
            return Qt.ItemFlag.NoItemFlags
        return Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsSelectable | Qt.ItemFlag.ItemIsEditable

    def setData(self, index, value, role=Qt.ItemDataRole.EditRole) -> bool:
        if role != Qt.ItemDataRole.EditRole or not index.isValid():
            return False
        self.editRequested.emit(index.row(), FIELDS[index.column()], str(value))
        return True


class LensletTable(QTableView):
    """A compact, row-selecting view of a :class:`LensletTableModel`; ``selectionEdited(rows)`` on user selection."""

    selectionEdited = Signal(object)  # noqa: N815 - Qt signal names are camelCase

    def __init__(self, model: LensletTableModel, parent=None) -> None:
        super().__init__(parent)
        self.setModel(model)
        self.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        self.setEditTriggers(
            QAbstractItemView.EditTrigger.DoubleClicked
            | QAbstractItemView.EditTrigger.EditKeyPressed
            | QAbstractItemView.EditTrigger.AnyKeyPressed
        )
        self.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.Stretch)
        self.horizontalHeader().setMinimumSectionSize(self.header_width())  # never clip a header
        frame = 2 * self.frameWidth() + self.verticalScrollBar().sizeHint().width()
        self.setMinimumWidth(
            len(HEADERS) * self.header_width() + self.verticalHeader().sizeHint().width() + frame
        )
        self.verticalHeader().setDefaultSectionSize(self.fontMetrics().height() + 6)
        self.setAlternatingRowColors(True)
        # A grey wash on the theme's own background: the palette's default (near white) left every
        # other row white under napari's dark theme, whose light text was then unreadable.
        self.setStyleSheet("QTableView { alternate-background-color: rgba(128, 128, 128, 40); }")
        self._quiet = False
        self.selectionModel().selectionChanged.connect(self._on_selection)

    def header_width(self) -> int:
        """Pixels the widest column header needs: its text and the header's margins on both sides."""
        header = self.horizontalHeader()
        margin = header.style().pixelMetric(QStyle.PixelMetric.PM_HeaderMargin, None, header)
        return max(header.fontMetrics().horizontalAdvance(text) for text in HEADERS) + 2 * margin + 8

    def selected_rows(self) -> list[int]:
        """Rows selected in the table, sorted."""
        return sorted({i.row() for i in self.selectionModel().selectedRows()})

    def select_rows(self, rows: Sequence[int]) -> None:
        """Select ``rows`` without emitting ``selectionEdited`` (state -> view); scrolls to them if they changed."""
        if sorted(rows) == self.selected_rows():
            return
        model = self.model()
        selection = QItemSelection()
        for r in rows:
            if 0 <= r < model.rowCount():
                selection.select(model.index(r, 0), model.index(r, model.columnCount() - 1))
        self._quiet = True
        try:
            flags = QItemSelectionModel.SelectionFlag.ClearAndSelect | QItemSelectionModel.SelectionFlag.Rows
            self.selectionModel().select(selection, flags)
            if rows:
                self.scrollTo(model.index(min(rows), 0))
        finally:
            self._quiet = False

    def _on_selection(self, *_args) -> None:
        if not self._quiet:
            self.selectionEdited.emit(self.selected_rows())
