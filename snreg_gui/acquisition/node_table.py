"""The acquisition screen's table of stored nodes: id, label, trocar x/y/z, own expected error, spread, gamma counts.

Why: the technician checks each node as it is stored, in a side column about 350 px wide at 1024x700; every column
must stay readable there: the id column is as wide as the widest node id, the label takes the room left, the numbers
fit their contents. A stored anatomical landmark is listed too, its name as its id and "landmark" as its label (in
italics), never taken for a node; its name spans the id and label cells, word-wrapped over the lines it needs (a
long name such as "left common iliac artery bifurcation" once widened the id column and pushed the label to "abe"
and the numbers off the screen).
"""

from __future__ import annotations

import math

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QAbstractItemView, QHeaderView, QSizePolicy, QTableWidget, QTableWidgetItem

from snreg.landmarks import LANDMARK
from snreg_gui.common.node_error import ERROR_CAPTION, ERROR_TIP, error_text
from snreg_gui.common.table_headers import fit_id_column, fit_spanned_rows

NODE_COLUMNS = ("id", "label", "x", "y", "z", ERROR_CAPTION, "spread", "counts")
NODE_TIPS = ("", "station label", "trocar frame, mm", "trocar frame, mm", "trocar frame, mm", ERROR_TIP,
             "spread of the stored fixes about their median, mm", "gamma counts typed at the store")


class StoredNodes(QTableWidget):
    """Read-only rows of stored nodes (:class:`~snreg.session.IntraopNode`), newest last and scrolled into view."""

    def __init__(self):
        super().__init__(0, len(NODE_COLUMNS))
        self.setHorizontalHeaderLabels(NODE_COLUMNS)
        self.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.verticalHeader().setVisible(False)
        self.verticalHeader().setDefaultSectionSize(self.fontMetrics().height() + 6)
        self.setMinimumHeight(self.fontMetrics().height() * 5)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Ignored)    # gets the room left
        header = self.horizontalHeader()
        header.setMinimumSectionSize(24)
        header.setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(NODE_COLUMNS.index("label"), QHeaderView.ResizeMode.Stretch)
        header.setSectionResizeMode(0, QHeaderView.ResizeMode.Fixed)      # the widest node id (_fit_ids)
        self.setWordWrap(True)
        for column, tip in enumerate(NODE_TIPS):
            self.horizontalHeaderItem(column).setToolTip(tip)
        self._fit_ids()

    def _fit_ids(self) -> None:
        """The id column as wide as the widest node id (landmark names span it and the label, wrapped)."""
        fit_id_column(self)

    def _fit_rows(self) -> None:
        """Landmark rows as high as their wrapped names; node rows one line."""
        fit_spanned_rows(self)

    def resizeEvent(self, event) -> None:                       # noqa: N802 (Qt's name)
        super().resizeEvent(event)
        self._fit_rows()

    def append(self, node) -> None:
        row = self.rowCount()
        self.insertRow(row)
        counts = "" if node.counts is None or math.isnan(node.counts) else f"{node.counts:g}"
        landmark = getattr(node, "kind", "") == LANDMARK
        cells = (node.id, "landmark" if landmark else node.label, *(f"{v:.1f}" for v in node.xyz_trocar),
                 error_text(node.cov_trocar_mm2),
                 f"{node.spread_mm:.2f}", counts)
        for column, text in enumerate(cells):
            item = QTableWidgetItem(text)
            if column >= NODE_COLUMNS.index("x"):
                item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
            if landmark:
                font = item.font()
                font.setItalic(True)
                item.setFont(font)
            self.setItem(row, column, item)
        if landmark:
            self.item(row, 0).setToolTip(f"anatomical landmark {node.id!r}: paired by name, never a node")
            self.setSpan(row, 0, 1, 2)
        self.item(row, NODE_COLUMNS.index("spread")).setToolTip(f"over {node.n_frames} fixes")
        self._fit_ids()
        self._fit_rows()
        self.scrollToBottom()

    def remove(self, node_id: str) -> None:
        """Drop the row of ``node_id`` (an undone node), if shown."""
        for row in range(self.rowCount()):
            if self.item(row, 0).text() == node_id:
                self.removeRow(row)
                self._fit_ids()
                return
