"""Give a table the width its text needs: columns sized to their contents, the table's room taken from its
neighbours in a splitter (the studio's default window must not elide values: "2.… µm" says nothing)."""

from __future__ import annotations

from qtpy.QtWidgets import QHeaderView, QSplitter, QTableWidget


def fit_columns(table: QTableWidget) -> None:
    """Every column as wide as its widest cell or header (the user may still drag a column)."""
    header = table.horizontalHeader()
    header.setStretchLastSection(False)
    header.setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)


def content_width(table: QTableWidget) -> int:
    """Pixels the table needs to show every column whole: columns, row header, frame and a vertical scroll bar."""
    table.resizeColumnsToContents()
    columns = sum(table.columnWidth(c) for c in range(table.columnCount()))
    row_header = table.verticalHeader().width() if table.verticalHeader().isVisible() else 0
    return columns + row_header + 2 * table.frameWidth() + table.verticalScrollBar().sizeHint().width()


def give_room(splitter: QSplitter, table: QTableWidget) -> None:
    """Widen ``table`` (a child of ``splitter``) to :func:`content_width`, taking the room from the others.

    The other widgets keep at least their minimum width; the table takes what is left when that is less.
    """
    index = splitter.indexOf(table)
    sizes = splitter.sizes()
    total = sum(sizes)
    if index < 0 or total <= 0:
        return  # not laid out yet
    others = [i for i in range(len(sizes)) if i != index]
    floor = sum(splitter.widget(i).minimumSizeHint().width() for i in others)
    wanted = min(content_width(table), max(total - floor, 0))
    rest = total - wanted
    other_total = sum(sizes[i] for i in others) or 1
    new = [0] * len(sizes)
    new[index] = wanted
    for i in others:
        new[i] = round(rest * sizes[i] / other_total)
    splitter.setSizes(new)
