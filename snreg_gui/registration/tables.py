"""The tables of the registration panel: a node table and the pairing table.

Why: both node sets and the pairing must be readable at a glance; a claim whose confidence is below
``CONFIDENT`` is shaded so the technician does not act on it, and its confidence is printed rounded down so the
digits never say 0.95 on a shaded row, nor 1.00 below 1 (:func:`~snreg.registration.wording.confidence_text`).
Each pair's expected distance (:func:`~snreg.registration.report.pair_expected_mm`) stands beside its distance. Rows
come from the Qt-free :func:`snreg.registration.report.pair_rows`, the same rows the CSV and PNG exports use.
"""

from __future__ import annotations

import numpy as np
from PySide6.QtGui import QBrush, QColor
from PySide6.QtWidgets import QAbstractItemView, QHeaderView, QTableWidget, QTableWidgetItem

from snreg.nodes import NodeSet
from snreg.registration import CONFIDENT
from snreg.registration.report import DOUBT_COLOUR, PairRow
from snreg.registration.wording import CHECK_WORDS, confidence_text
from snreg_gui.common.table_headers import two_line_headers  # noqa: F401 (the panel takes it from here)

NODE_COLUMNS = ("id", "label", "x mm", "y mm", "z mm")
PAIR_COLUMNS = ("intraop id", "intraop label", "hot spot", "hot spot label", "with", "distance mm", "expected mm",
                "leave-one-out mm", "confidence")
EXPECTED_TIP = ("the 90 % bound on this pair's distance were its claim right and the node left out of the fit (its "
                "leave-one-out distance lies within it 9 times in 10; its distance within the fit, smaller still): "
                "the node's own error (its covariance) and the hot spot's expected error T from the registration (the "
                "fit's error there, the hot spot's own and the unmodelled error) together; T alone when the stored "
                "nodes carry no covariances. Beyond it: check the pair")


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
    """One row per intraop node: the hot spot (preop node) it came from ("none" for no imaged hot spot), the other
    nodes from the same hot spot, distance, expected distance (:data:`EXPECTED_TIP`), leave-one-out distance (the
    node's distance when the other pairs alone register: large for a node the others disagree with) and confidence,
    shaded when doubtful."""

    def __init__(self, parent=None):
        super().__init__(0, len(PAIR_COLUMNS), parent)
        _configure(self, PAIR_COLUMNS)
        self.horizontalHeaderItem(PAIR_COLUMNS.index("leave-one-out mm")).setToolTip(
            "the node's distance from its hot spot when the other pairs alone register")
        self.horizontalHeaderItem(PAIR_COLUMNS.index("hot spot")).setToolTip(
            "the SPECT hot spot (preop node) this node came from; none: from no imaged hot spot")
        self.horizontalHeaderItem(PAIR_COLUMNS.index("with")).setToolTip(
            "the other stored nodes that came from the same hot spot (SPECT shows nodes closer than 10-15 mm as one)")
        self.horizontalHeaderItem(PAIR_COLUMNS.index("expected mm")).setToolTip(EXPECTED_TIP)
        self.horizontalHeaderItem(PAIR_COLUMNS.index("confidence")).setToolTip(
            f"the probability that the claim is right, rounded down (1.00 only when certain); below {CONFIDENT:g} the "
            "row is shaded: confirm that node's label or store it again")

    def selected_intraop_ids(self) -> list[str]:
        """The intraop ids of the selected rows."""
        rows = sorted({index.row() for index in self.selectedIndexes()})
        return [self.item(row, 0).text() for row in rows if self.item(row, 0) is not None]

    def show_rows(self, rows: list[PairRow], expected_mm=()) -> None:
        """The rows, with each node's expected distance (mm, NaN or missing: none) beside its distance."""
        self.setRowCount(len(rows))
        doubt = QBrush(QColor(DOUBT_COLOUR))
        expected = list(expected_mm) + [np.nan] * (len(rows) - len(expected_mm))
        for row, (pair, bound) in enumerate(zip(rows, expected)):
            cells = [pair.intraop_id, pair.intraop_label, pair.preop_id, pair.preop_label, " ".join(pair.shared_with),
                     f"{pair.distance_mm:.1f}", _mm(bound), _mm(pair.leave_one_out_mm), confidence_text(pair.confidence)]
            for column, text in enumerate(cells):
                item = QTableWidgetItem(text)
                if not pair.confident:
                    item.setBackground(doubt)
                    item.setToolTip(f"confidence {confidence_text(pair.confidence, 4)} is {CHECK_WORDS}")
                self.setItem(row, column, item)


def _mm(value: float) -> str:
    return "" if np.isnan(value) else f"{value:.1f}"


def _configure(table: QTableWidget, columns) -> None:
    table.setHorizontalHeaderLabels(columns)
    table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
    table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
    table.verticalHeader().setVisible(False)
    table.verticalHeader().setDefaultSectionSize(table.fontMetrics().height() + 6)
    table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.Stretch)
