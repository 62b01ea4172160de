"""The registration panel's list of the registrations stored in the session, and the "final" mark.

Why: every Run is stored, so the operator must be able to say which one counts; the one marked final is kept in the
session (:meth:`snreg.session.Session.set_final_registration`) and the exports use it. This widget only shows the
list and asks; the panel writes the mark in a worker.

>>> stored = StoredList()
>>> stored.final_requested.connect(panel_slot)      # int: mark that registration final; None: unmark
>>> stored.show_stored(session.registrations())
"""

from __future__ import annotations

from PySide6.QtCore import Signal
from PySide6.QtWidgets import (QAbstractItemView, QGroupBox, QHBoxLayout, QHeaderView, QPushButton, QTableWidget,
                               QTableWidgetItem, QVBoxLayout)

STORED_COLUMNS = ("#", "method", "RMS mm", "paired", "final")
FINAL_MARK = "FINAL"


def stored_rows(registrations) -> list[list[str]]:
    """One row per :class:`~snreg.session.StoredRegistration`: number, method, RMS, pairs, the final mark."""
    return [[str(r.n), r.result.method, f"{r.result.rms_mm:.2f}",
             f"{int((r.result.pairing >= 0).sum())} of {len(r.result.pairing)}", FINAL_MARK if r.final else ""]
            for r in registrations]


class StoredList(QGroupBox):
    """The stored registrations, newest last, with "Mark selected final" and "Unmark final"."""

    final_requested = Signal(object)

    def __init__(self, parent=None):
        super().__init__("Stored registrations (the one marked final is exported)", parent)
        self.table = QTableWidget(0, len(STORED_COLUMNS))
        self.table.setHorizontalHeaderLabels(STORED_COLUMNS)
        self.table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.Stretch)
        self.table.verticalHeader().hide()
        self.table.setMaximumHeight(120)
        self.mark_button = QPushButton("Mark selected final")
        self.mark_button.setToolTip("keep the selected registration in the session as the one that counts; the "
                                    "exports use it from now on")
        self.unmark_button = QPushButton("Unmark final")
        self._numbers: list[int] = []
        buttons = QHBoxLayout()
        buttons.addWidget(self.mark_button)
        buttons.addWidget(self.unmark_button)
        buttons.addStretch(1)
        layout = QVBoxLayout(self)
        layout.addWidget(self.table)
        layout.addLayout(buttons)
        self.mark_button.clicked.connect(self._mark)
        self.unmark_button.clicked.connect(lambda: self.final_requested.emit(None))
        self.table.itemSelectionChanged.connect(self._update_buttons)
        self.show_stored([])

    def show_stored(self, registrations, writable: bool = True) -> None:
        """List ``registrations`` (select the newest); the buttons only where the mark can be written."""
        registrations = list(registrations)
        self._numbers = [r.n for r in registrations]
        self._has_final = any(r.final for r in registrations)
        self._writable = writable
        rows = stored_rows(registrations)
        self.table.setRowCount(len(rows))
        for r, row in enumerate(rows):
            for c, text in enumerate(row):
                self.table.setItem(r, c, QTableWidgetItem(text))
        if registrations:
            self.table.selectRow(len(registrations) - 1)
        self._update_buttons()

    def _update_buttons(self) -> None:
        self.mark_button.setEnabled(self._writable and bool(self.table.selectionModel().selectedRows()))
        self.unmark_button.setEnabled(self._writable and self._has_final)

    def _mark(self) -> None:
        rows = self.table.selectionModel().selectedRows()
        if rows:
            self.final_requested.emit(self._numbers[rows[0].row()])
