"""Table headers that fit a narrow window: each caption over two lines, each column as wide as its contents.

Why: at 1024x700 a table in a side column or a wizard page had columns past its right edge, reachable only by a
horizontal scroll bar, and captions cut; a caption's last word on a line of its own ("camera" over "x") keeps the
columns narrow. Used by the registration panel's pairing table, the trocar wizard's sample tables and the review's
stored nodes. A node table's id column is as wide as its widest node id, a landmark's long name spanning it and the
next column, word-wrapped (:func:`fit_id_column`, the acquisition and review tables; :func:`fit_spanned_rows` makes
such rows as high as their lines where the rows are not sized to their contents anyway).
"""

from __future__ import annotations

from PySide6.QtWidgets import QHeaderView, QStyle


def two_line_headers(table) -> None:
    """Header captions over two lines ("leave-one-out mm" as "leave-one-out" over "mm"), each column as wide as its
    contents, so no caption is cut in a narrow window; label columns take the room left."""
    header = table.horizontalHeader()
    for column in range(table.columnCount()):
        item = table.horizontalHeaderItem(column)
        words = item.text().rsplit(" ", 1)
        item.setText("\n".join(words))
        mode = QHeaderView.ResizeMode.Stretch if words[-1] == "label" else QHeaderView.ResizeMode.ResizeToContents
        header.setSectionResizeMode(column, mode)


def fit_id_column(table, least: str = "SN88") -> None:
    """Column 0 as wide as its widest id (at least ``least``), landmark names left out: they span it and the next
    column, word-wrapped (:func:`fit_spanned_rows`), so a long name never widens it and pushes the numbers off."""
    header = table.horizontalHeader()
    header.setSectionResizeMode(0, QHeaderView.ResizeMode.Fixed)
    ids = [table.item(row, 0).text() for row in range(table.rowCount())
           if table.columnSpan(row, 0) == 1 and table.item(row, 0) is not None]
    caption = table.horizontalHeaderItem(0).text().split("\n")
    margin = 2 * table.style().pixelMetric(QStyle.PixelMetric.PM_HeaderMargin) + 8
    width = max(table.fontMetrics().horizontalAdvance(text) for text in [*caption, least, *ids]) + margin
    if header.sectionSize(0) != width:
        header.resizeSection(0, width)


def fit_spanned_rows(table) -> None:
    """Rows whose first cell spans columns (a landmark's name) as high as their wrapped text; the others one line."""
    for row in range(table.rowCount()):
        if table.columnSpan(row, 0) > 1:
            table.resizeRowToContents(row)
