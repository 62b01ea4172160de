"""The tables of the registration panel: a node table and the pairing table.

Why: both node sets and the pairing must be readable at a glance; a pairing whose confidence is below
``CONFIDENT`` is shaded so the technician does not act on it. Rows come from the Qt-free
:func:`snreg.registration.report.pair_rows`, the same rows the CSV and PNG exports use.
"""

from __future__ import annotations

import numpy as np
from PySide6.QtGui import QBrush, QColor
from PySide6.QtWidgets import QAbstractItemView, QHeaderView, QTableWidget, QTableWidgetItem

from snreg.nodes import NodeSet
from snreg.registration import CONFIDENT
from snreg.registration.report import DOUBT_COLOUR, PairRow

NODE_COLUMNS = ("id", "label", "x mm", "y mm", "z mm")
PAIR_COLUMNS = ("intraop id", "intraop label", "preop id", "preop label", "distance mm", "leave-one-out mm",
                "confidence")


class NodeTable(QTableWidget):
    """Read-only id, label, x, y, z (mm) of a node set."""

    def __init__(self, parent=None):
        super().__init__(0, len(NODE_COLUMNS), parent)
        _configure(self, NODE_COLUMNS)
        self.setMinimumHeight(120)
        self.setMaximumHeight(200)

    def show_nodes(self, nodes: NodeSet | None) -> None:
        n = 0 if nodes is None else len(nodes)
        self.setRowCount(n)
        for row in range(n):
            cells = [nodes.ids[row], nodes.labels[row]] + [f"{v:.1f}" for v in nodes.xyz[row]]
            for column, text in enumerate(cells):
                self.setItem(row, column, QTableWidgetItem(text))


class PairingTable(QTableWidget):
    """One row per intraop node: its preop partner ("extra" if none), distance, leave-one-out distance (the node's
    distance when the other pairs alone register: large for a node the others disagree with) and confidence, shaded
    when doubtful."""

    def __init__(self, parent=None):
        super().__init__(0, len(PAIR_COLUMNS), parent)
        _configure(self, PAIR_COLUMNS)
        self.horizontalHeaderItem(PAIR_COLUMNS.index("leave-one-out mm")).setToolTip(
            "the node's distance from its partner when the other pairs alone register")

    def selected_intraop_ids(self) -> list[str]:
        """The intraop ids of the selected rows."""
        rows = sorted({index.row() for index in self.selectedIndexes()})
        return [self.item(row, 0).text() for row in rows if self.item(row, 0) is not None]

    def show_rows(self, rows: list[PairRow]) -> None:
        self.setRowCount(len(rows))
        doubt = QBrush(QColor(DOUBT_COLOUR))
        for row, pair in enumerate(rows):
            cells = [pair.intraop_id, pair.intraop_label, pair.preop_id, pair.preop_label,
                     f"{pair.distance_mm:.1f}", "" if np.isnan(pair.leave_one_out_mm) else f"{pair.leave_one_out_mm:.1f}",
                     f"{pair.confidence:.2f}"]
            for column, text in enumerate(cells):
                item = QTableWidgetItem(text)
                if not pair.confident:
                    item.setBackground(doubt)
                    item.setToolTip(f"confidence {pair.confidence:.2f} is below {CONFIDENT:g}: check this pairing")
                self.setItem(row, column, item)


def _configure(table: QTableWidget, columns) -> None:
    table.setHorizontalHeaderLabels(columns)
    table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
    table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
    table.verticalHeader().setVisible(False)
    table.verticalHeader().setDefaultSectionSize(table.fontMetrics().height() + 6)
    table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.Stretch)
