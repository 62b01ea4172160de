"""Table headers that fit a narrow window: each caption over two lines, each column as wide as its contents.

Why: at 1024x700 a table in a side column or a wizard page had columns past its right edge, reachable only by a
horizontal scroll bar, and captions cut; a caption's last word on a line of its own ("camera" over "x") keeps the
columns narrow. Used by the registration panel's pairing table and the trocar wizard's sample tables.
"""

from __future__ import annotations

from PySide6.QtWidgets import QHeaderView


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
