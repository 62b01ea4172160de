"""The registration panel's anatomical landmarks: listed apart from the hot spots, given to the run, said in words.

Why: a patient with one or two sentinel nodes registers when landmarks (e.g. the aortic bifurcation, found on the CT
and touched with the probe) make up the three points (docs/design.md, Contracts). A landmark pair enters the fit with its
correspondence known, so a wrong one (a name given to the wrong vessel) must never be trusted silently (issue 29):
the panel lists every landmark with the side(s) it is on, each pair's residual and leave-one-out residual, and says
a suspect in words, in :mod:`snreg.registration.landmark_report`'s wording (the same as ``snreg register``). A mixin of
the panel (:class:`PanelLandmarks`), using its ``preop_box`` (``landmarks``: read with the preop nodes),
``landmark_table``, ``summary``, ``alignment`` and ``_excluded``; the intraop landmarks come from the session or an
opened intraop node file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QAbstractItemView, QHeaderView, QTableWidget, QTableWidgetItem

from snreg.nodes import NodeFile, NodeSet
from snreg.registration.landmark_report import landmark_notes, landmark_rows, unchecked_note
from snreg.workflow.registration_run import RunRecord, RunRequest

NO_CT_LANDMARKS = "no CT landmarks loaded: load them with Landmarks... beside the preop nodes"
MIN_POINTS = 3          # nodes plus landmark pairs a registration needs, at least one of them a node (docs/design.md, Contracts)
LANDMARK_COLUMNS = ("landmark", "CT", "surgery", "dist (mm)", "loo (mm)", "check")
LANDMARK_TIPS = ("anatomical landmark, paired by name (never a hot spot)", "found on the CT (with the preop nodes)",
                 "touched with the probe and stored (Store landmark)",
                 "its distance from its CT position mapped by the registration, mm",
                 "its distance when the nodes and the other landmarks alone register, mm",
                 "what to check: a landmark left out as contradicting the rest, or given on one side only")


def names(marks: NodeSet | None) -> list[str]:
    return [] if marks is None else list(marks.ids)


def paired_names(preop: NodeSet | None, intraop: NodeSet | None) -> list[str]:
    """The landmark names given on both sides (the pairs a registration uses), sorted."""
    return sorted(set(names(preop)) & set(names(intraop)))


def needed_nodes(pairs: int) -> int:
    """Nodes each side needs beside ``pairs`` landmark pairs: three points in all, one node at least."""
    return max(1, MIN_POINTS - pairs)


@dataclass(frozen=True)
class LandmarkLine:
    """One row of the landmark table: the name, on which sides, the pair's figures (NaN before a run), the check."""

    name: str
    on_ct: bool
    touched: bool
    residual_mm: float = math.nan
    leave_one_out_mm: float = math.nan
    check: str = ""


def landmark_lines(preop: NodeSet | None, intraop: NodeSet | None, result=None) -> list[LandmarkLine]:
    """Every landmark named on either side, paired ones first (by name), with ``result``'s figures when given."""
    rows = {row.name: row for row in (landmark_rows(result) if result is not None else [])}
    ct, touched = set(names(preop)), set(names(intraop))
    lines = []
    for name in sorted(ct | touched, key=lambda n: (not (n in ct and n in touched), n)):
        row = rows.get(name)
        if row is not None and row.suspect:
            check = "SUSPECT: left out of the fit"
        elif name not in touched:
            check = "CT only: touch it and store it"
        elif not ct:
            check = NO_CT_LANDMARKS
        elif name not in ct:
            check = "not among the CT's landmarks: check its name"
        else:
            check = "" if row is not None or result is None else "not used"
        lines.append(LandmarkLine(name, name in ct, name in touched, math.nan if row is None else row.residual_mm,
                                  math.nan if row is None else row.leave_one_out_mm, check))
    return lines


def landmark_warnings(record: RunRecord) -> list[str]:
    """The result's landmark sentences (:func:`~snreg.registration.landmark_report.landmark_notes`), a suspect pair and
    landmarks the points cannot check marked WARNING."""
    notes = landmark_notes(record.result, names(record.preop_landmarks), names(record.intraop_landmarks))
    warned = {unchecked_note(record.result)} | {text for text in notes if "contradicts" in text}
    return [f"WARNING: {text[0].upper()}{text[1:]}." if text in warned else f"{text[0].upper()}{text[1:]}."
            for text in notes]


def _mm(value: float) -> str:
    return "" if math.isnan(value) else f"{value:.1f}"


class LandmarkTable(QTableWidget):
    """Read-only rows of :class:`LandmarkLine`; hidden while there are no landmarks on either side."""

    def __init__(self):
        super().__init__(0, len(LANDMARK_COLUMNS))
        self.setHorizontalHeaderLabels(LANDMARK_COLUMNS)
        for column, tip in enumerate(LANDMARK_TIPS):
            self.horizontalHeaderItem(column).setToolTip(tip)
        self.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.setSelectionMode(QAbstractItemView.SelectionMode.NoSelection)
        self.verticalHeader().setVisible(False)
        self.verticalHeader().setDefaultSectionSize(self.fontMetrics().height() + 6)
        header = self.horizontalHeader()
        header.setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
        header.setSectionResizeMode(0, QHeaderView.ResizeMode.Stretch)
        self.setVisible(False)

    def show_lines(self, lines: list[LandmarkLine]) -> None:
        self.setRowCount(len(lines))
        for r, line in enumerate(lines):
            cells = (line.name, "yes" if line.on_ct else "-", "yes" if line.touched else "-", _mm(line.residual_mm),
                     _mm(line.leave_one_out_mm), line.check)
            for c, text in enumerate(cells):
                item = QTableWidgetItem(text)
                if c in (3, 4):
                    item.setTextAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                if line.check.startswith("SUSPECT"):
                    item.setForeground(Qt.GlobalColor.red)
                self.setItem(r, c, item)
        self._fit_height()
        self.setVisible(bool(lines))

    def _fit_height(self) -> None:
        """Rows as high as their word-wrapped names (a long name wraps in a narrow panel rather than be cut), the
        table as high as its first four rows."""
        self.resizeRowsToContents()
        rows = sum(self.rowHeight(r) for r in range(min(self.rowCount(), 4)))
        self.setFixedHeight(self.horizontalHeader().sizeHint().height() + rows + 2 * self.frameWidth())

    def resizeEvent(self, event) -> None:                       # noqa: N802 (Qt's name)
        super().resizeEvent(event)
        self._fit_height()

    def column(self, name: str) -> list[str]:
        """The texts of column ``name`` (tests, screenshots)."""
        c = LANDMARK_COLUMNS.index(name)
        return [self.item(r, c).text() for r in range(self.rowCount())]


class PanelLandmarks:
    """The panel's landmarks (module docstring)."""

    _intraop_landmarks: NodeSet | None = None     # the session's stored landmarks, or an intraop node file's

    def landmark_pairs(self) -> list[str]:
        """The landmark names on both sides now (the pairs the next run uses)."""
        return paired_names(self.preop_box.landmarks, self._intraop_landmarks)

    def set_intraop_landmarks(self, landmarks: NodeSet | None) -> None:
        """Use these intraop landmarks (trocar frame, mm; ids = names; None or empty: none)."""
        self._intraop_landmarks = landmarks if landmarks is not None and len(landmarks) else None

    def _preop_landmarks_changed(self, _landmarks) -> None:
        """A landmark file read or the landmarks cleared in the preop box: the preop set saved with them in a writable
        session (as new preop nodes are), and the result shown no longer answers the inputs."""
        self._save_preop(self.preop_box.nodes)
        self._inputs_changed()

    def _intraop_file_read(self, read: NodeFile) -> None:
        """An intraop node file read: its landmarks apart, its nodes as the intraop nodes."""
        self.set_intraop_landmarks(read.landmarks)
        self.set_intraop_nodes(read.nodes)

    def _with_landmarks(self, request: RunRequest) -> RunRequest:
        """``request`` with the landmarks of both sides; with pairs, the initial alignment's centroids take the
        paired landmarks too (with one node the nodes' centroids alone say little)."""
        preop, intraop = self.preop_box.landmarks, self._intraop_landmarks
        request = replace(request, preop_landmarks=preop, intraop_landmarks=intraop)
        pairs = paired_names(preop, intraop)
        if not pairs:
            return request
        ct = preop.xyz[[preop.ids.index(n) for n in pairs]]
        touched = intraop.xyz[[intraop.ids.index(n) for n in pairs]]
        return replace(request, initial=self.alignment.transform(np.vstack([request.preop.xyz, ct]),
                                                                 np.vstack([request.intraop.xyz, touched])))

    def _landmark_scene(self, record: RunRecord | None, transform) -> dict:
        """The landmarks for the node view, the preop ones under ``transform`` (4x4 intraop_from_preop), and the
        landmark table filled: the figures of ``record`` (the result shown and current) or the sides alone."""
        preop, intraop = self.preop_box.landmarks, self._intraop_landmarks
        result = None if record is None else record.result
        if record is not None:
            preop, intraop = record.preop_landmarks, record.intraop_landmarks
        self.landmark_table.show_lines(landmark_lines(preop, intraop, result))
        return {"preop_landmarks": None if preop is None else preop.moved(transform, "trocar"),
                "intraop_landmarks": intraop,
                "suspects": tuple(() if result is None else result.landmarks_suspect or ())}

    def _landmark_summary(self, record: RunRecord | None) -> None:
        """Append the result's landmark sentences (a suspect pair in words) to the summary."""
        if record is not None:
            lines = landmark_warnings(record)
            if lines:
                self.summary.setText("\n".join([self.summary.text()] + lines))
