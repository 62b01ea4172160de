"""The review screen's panels: the header text, the stored-nodes and preop tables, the snapshot pair and the
registrations.

Why: each shows one part of a :class:`~snreg.session.timeline.SessionReview` that is already in memory;
nothing here reads files or computes more than a format string.

>>> header.setText(header_text(review)); fill_node_table(table, review.stored)    # nodes and landmarks
>>> snapshots.show_pair(node.left_rgb, node.right_rgb)
>>> registrations.show_registrations(review.registrations)   # none chosen: no pairs, "choose a registration"
>>> caption.setText(preop_text(review)); fill_table(preop_table, preop_rows(review))
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (QAbstractItemView, QHBoxLayout, QHeaderView, QLabel, QPushButton, QStackedWidget,
                               QTableWidget, QTableWidgetItem, QVBoxLayout, QWidget)

from snreg.registration.naming import marked_rows, pair_text
from snreg.registration.wording import confidence_text
from snreg.session.timeline import ReviewNode, ReviewRegistration, SessionReview
from snreg_gui.common.feed_view import FeedView
from snreg_gui.common.node_error import ERROR_CAPTION, ERROR_TIP, error_text
from snreg_gui.common.table_headers import fit_id_column, two_line_headers

# the stored nodes' columns (keys; shown over two lines): what a reviewer compares between nodes. The rest of a node's
# record (camera position, spread, frames, counts) is in its row's tooltip: with all ten columns the table ran past
# its right edge at every window size (issue 35)
NODE_COLUMNS = ("id", "label", "time (s)", "trocar x, y, z (mm)", f"{ERROR_CAPTION} (mm)", "insertion (mm)")
INSERTION_TIP = ("the camera's insertion (pivot to camera) the node was mapped with, tracked from the video; "
                 "empty: not tracked, the chain's distance")
LANDMARK_MARK = "landmark: "
LANDMARK_TIP = ("an anatomical landmark touched with the probe (Store landmark): not a node, never counted or paired "
                "as one")
REGISTRATION_COLUMNS = ("#", "method", "RMS (mm)", "paired", "final")
PAIRING_COLUMNS = ("intraop -> hot spot", "distance (mm)", "confidence")
PREOP_COLUMNS = ("id", "label", "x, y, z (mm)", "counts")
CHOOSE_REGISTRATION = "choose a registration above to see its pairs"
NO_PREOP = "no preop nodes stored in this session"


def preop_text(review: SessionReview) -> str:
    """The preop set in one line: how many nodes and landmarks, their frame, and what gives their down."""
    preop = review.preop
    if preop is None:
        return NO_PREOP
    marks = 0 if review.preop_landmarks is None else len(review.preop_landmarks)
    and_marks = f" and {marks} landmark{'s' * (marks != 1)}" if marks else ""
    frame = f" ({preop.frame})" if preop.frame else ""
    down = review.preop_down
    gravity = ("down: not stored (no patient position)" if down is None else
               f"down from {down.source}" + (f"; {down.problem}" if down.problem else
                                             ": " + ", ".join(f"{c:.3f}" for c in down.vector)))
    return f"{len(preop)} preop node{'s' * (len(preop) != 1)}{and_marks}{frame}; {gravity}"


def preop_rows(review: SessionReview) -> list[list[str]]:
    """The preop nodes, then their landmarks (id cell "landmark: <name>")."""
    preop = review.preop
    if preop is None:
        return []
    counts = [math.nan] * len(preop) if preop.counts is None else preop.counts
    marks = review.preop_landmarks
    return ([[i, label, _xyz(xyz), _number(float(c), 0)] for i, label, xyz, c in
             zip(preop.ids, preop.labels, preop.xyz, counts)]
            + ([] if marks is None else [[f"{LANDMARK_MARK}{i}", label, _xyz(xyz), ""]
                                         for i, label, xyz in zip(marks.ids, marks.labels, marks.xyz)]))


def header_text(review: SessionReview) -> str:
    """What the file is: case, creation, versions, intact or read from its journal, calibration, streams."""
    lines = [f"file: {review.path}",
             f"case {review.case_id}, created {review.created_utc or 'unknown'} (UTC), snreg {review.snreg_version}, "
             f"format version {review.format_version}"]
    if review.damaged:
        what = review.problems[0] if review.problems else "the HDF5 file was unreadable in part"
        more = f" (and {len(review.problems) - 1} more)" if len(review.problems) > 1 else ""
        lines.append(f"DAMAGED: {what}{more}; the rest was read around it, the journal's records from the journal; "
                     "'snreg session recover' rebuilds a clean file")
    rms = review.stereo_rms_px
    stereo = ("stereo not stored" if rms is None else
              "stereo RMS not recorded" if math.isnan(rms) else f"stereo RMS {rms:.2f} px")
    chain = ("chain not stored" if review.imu_trocar_mm is None else
             f"chain IMU-trocar {review.imu_trocar_mm:.1f} mm, trocar-camera {review.trocar_camera_mm:.1f} mm")
    lines.append(f"calibration: {stereo}; {chain}")
    frames = review.frames
    frame_text = f"frames {len(frames.t_s)}"
    if len(frames.t_s) > 1:
        gaps = len(frames.gaps_s)
        longest = f", longest {frames.gaps_s[:, 1].max():.2f} s" if gaps else ""
        frame_text += f" ({frames.median_rate_hz:.1f}/s median, {gaps} gap{'' if gaps == 1 else 's'}{longest})"
    camera = review.camera
    insertion = (f", insertion tracked on {int(camera.tracked.sum())} pairs, lost on {int((~camera.tracked).sum())}"
                 if len(camera.t_s) else ", insertion not tracked")
    lines.append(f"streams: IMU {len(review.imu.t_s)} samples, probe {len(review.probe.t_s)} fixes, {frame_text}"
                 f"{insertion}")
    return "\n".join(lines)


def read_only_table(columns: Sequence[str]) -> QTableWidget:
    """A table of whole-row, single selections that the user cannot edit."""
    table = QTableWidget(0, len(columns))
    table.setHorizontalHeaderLabels(list(columns))
    table.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
    table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
    table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
    table.horizontalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)
    table.verticalHeader().hide()
    return table


def fill_table(table: QTableWidget, rows: Sequence[Sequence[str]]) -> None:
    table.clearContents()
    table.setRowCount(len(rows))
    for r, row in enumerate(rows):
        for c, text in enumerate(row):
            table.setItem(r, c, QTableWidgetItem(text))


def node_rows(nodes: Sequence[ReviewNode]) -> list[list[str]]:
    """One row per stored point, in :data:`NODE_COLUMNS`; a landmark's id cell says so ("landmark: aortic
    bifurcation")."""
    return [[f"{LANDMARK_MARK}{n.id}" if n.is_landmark else n.id, n.label, f"{n.t_s:.2f}", _xyz(n.xyz_trocar),
             error_text(n.cov_trocar_mm2), _number(n.trocar_camera_mm, 1)] for n in nodes]


def node_details(node: ReviewNode) -> str:
    """The rest of a stored point's record, for its row's tooltip: camera position, spread, fixes, counts."""
    counts = _number(node.counts, 0)
    return (f"camera x, y, z: {_xyz(node.xyz_camera)} mm; spread {_number(node.spread_mm, 2)} mm over "
            f"{node.n_frames} fixes" + (f"; counts {counts}" if counts else "; no counts typed"))


def node_table() -> QTableWidget:
    """The stored nodes' table: captions over two lines, the id column as wide as the node ids, a landmark's name
    spanning the id and label cells, word-wrapped; every column inside a side pane at 1024x700."""
    table = read_only_table(NODE_COLUMNS)
    table.horizontalHeaderItem(NODE_COLUMNS.index("insertion (mm)")).setToolTip(INSERTION_TIP)
    table.horizontalHeaderItem(NODE_COLUMNS.index(f"{ERROR_CAPTION} (mm)")).setToolTip(ERROR_TIP)
    two_line_headers(table)
    table.setWordWrap(True)
    fit_id_column(table)
    table.verticalHeader().setSectionResizeMode(QHeaderView.ResizeMode.ResizeToContents)  # a wrapped name's lines
    return table


def fill_node_table(table: QTableWidget, points: Sequence[ReviewNode]) -> None:
    """The stored nodes and landmarks in the order stored, each row's tooltip the rest of its record
    (:func:`node_details`); a landmark's row in italics, its name across the id and label cells, with a tooltip (an
    anatomical point touched with the probe, never a node: not counted, never paired as a hot spot's)."""
    table.clearSpans()
    fill_table(table, node_rows(points))
    for row, point in enumerate(points):
        details = node_details(point)
        for column in range(table.columnCount()):
            item = table.item(row, column)
            item.setData(Qt.ItemDataRole.ToolTipRole, f"{LANDMARK_TIP}\n{details}" if point.is_landmark else details)
            if point.is_landmark:
                font = item.font()
                font.setItalic(True)
                item.setFont(font)
        if point.is_landmark:
            table.setSpan(row, 0, 1, 2)
    fit_id_column(table)


def _xyz(v: np.ndarray) -> str:
    return ", ".join(_number(c, 1) for c in v)


def _number(value: float, decimals: int) -> str:
    return "" if math.isnan(value) else f"{value:.{decimals}f}"


class SnapshotPair(QWidget):
    """The left and right snapshots of one node, RGB (H, W, 3), side by side; each caption says its size or that
    there is none."""

    def __init__(self):
        super().__init__()
        self.left_view, self.right_view = FeedView("left"), FeedView("right")
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.left_view)
        layout.addWidget(self.right_view)

    def show_video_frame(self, frame) -> None:
        """A recorded pair (:class:`~snreg.session.review_video.ReviewFrame`) with its probe overlay."""
        for side, view, rgb, overlay in (("left", self.left_view, frame.left_rgb, frame.overlay_left),
                                         ("right", self.right_view, frame.right_rgb, frame.overlay_right)):
            view.title = f"{side}: frame {frame.row} at {frame.t_s:.2f} s" + ("" if overlay is not None else
                                                                             ", no fix")
            view.show_frame(rgb, overlay)

    def show_pair(self, left_rgb: np.ndarray | None, right_rgb: np.ndarray | None) -> None:
        for side, view, rgb in (("left", self.left_view, left_rgb), ("right", self.right_view, right_rgb)):
            if rgb is None:
                view.clear(f"{side}: no snapshot")
                continue
            view.title = f"{side} ({rgb.shape[1]} x {rgb.shape[0]})"
            view.show_frame(rgb)


class StoredRegistrations(QWidget):
    """The stored registrations (method, RMS, how many nodes paired, the final mark) and the selected one's pairing
    table ("SN1 -> P3"); "Mark selected final" / "Unmark final" emit ``final_requested(n or None)``."""

    final_requested = Signal(object)

    def __init__(self):
        super().__init__()
        self.list = read_only_table(REGISTRATION_COLUMNS)
        self.pairs = read_only_table(PAIRING_COLUMNS)
        self.empty = QLabel("no registration stored")
        self.choose_hint = QLabel(CHOOSE_REGISTRATION)       # in the pairs' place while none is chosen
        self.choose_hint.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.choose_hint.setWordWrap(True)
        self.pairs_place = QStackedWidget()                 # the hint or the pairs, never both; no taller than the table
        self.pairs_place.addWidget(self.pairs)
        self.pairs_place.addWidget(self.choose_hint)
        self.mark_button = QPushButton("Mark selected final")
        self.mark_button.setToolTip("keep the selected registration in the session file as the one that counts")
        self.unmark_button = QPushButton("Unmark final")
        buttons = QHBoxLayout()
        buttons.addWidget(self.mark_button)
        buttons.addWidget(self.unmark_button)
        buttons.addStretch(1)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        for widget in (self.empty, self.list):
            layout.addWidget(widget)
        layout.addLayout(buttons)
        layout.addWidget(self.pairs_place)
        self._registrations: list[ReviewRegistration] = []
        self.list.itemSelectionChanged.connect(self._show_selected)
        self.mark_button.clicked.connect(self._mark)
        self.unmark_button.clicked.connect(lambda: self.final_requested.emit(None))
        self._update_buttons()

    def show_registrations(self, registrations: Sequence[ReviewRegistration]) -> None:
        """List ``registrations``, none chosen: the pairs table stays empty until one is (a table of pairs beside
        an unselected list passed for the newest one's without saying so)."""
        self._registrations = list(registrations)
        self.list.clearSelection()
        fill_table(self.list, [[str(r.n), r.method, f"{r.rms_mm:.2f}", f"{r.n_paired} of {len(r.intraop_ids)}",
                                "FINAL" if r.final else ""] for r in self._registrations])
        self.empty.setVisible(not self._registrations)
        self._show_selected()

    @property
    def chosen(self) -> int | None:
        """The number of the registration chosen (None: none)."""
        rows = self.list.selectionModel().selectedRows()
        return self._registrations[rows[0].row()].n if rows else None

    def choose(self, n: int) -> None:
        """Choose registration ``n`` (its pairs shown); nothing when there is none of that number."""
        rows = [k for k, reg in enumerate(self._registrations) if reg.n == n]
        if rows:
            self.list.selectRow(rows[0])

    def show_final(self, n: int | None) -> None:
        """Show ``n`` as the one marked final (None: none), keeping the selection."""
        self._registrations = [replace(r, final=r.n == n) for r in self._registrations]
        for row, reg in enumerate(self._registrations):
            self.list.setItem(row, REGISTRATION_COLUMNS.index("final"), QTableWidgetItem("FINAL" if reg.final else ""))
        self._update_buttons()

    def _update_buttons(self) -> None:
        self.mark_button.setEnabled(bool(self.list.selectionModel().selectedRows()))
        self.unmark_button.setEnabled(any(r.final for r in self._registrations))

    def _mark(self) -> None:
        rows = self.list.selectionModel().selectedRows()
        if rows:
            self.final_requested.emit(self._registrations[rows[0].row()].n)

    def _show_selected(self) -> None:
        self._update_buttons()
        rows = self.list.selectionModel().selectedRows()
        self.pairs_place.setCurrentWidget(self.choose_hint if self._registrations and not rows else self.pairs)
        if not rows:
            fill_table(self.pairs, [])
            return
        reg = self._registrations[rows[0].row()]
        shown = marked_rows(reg.rows, [row.preop_id for row in reg.rows if row.paired])
        fill_table(self.pairs, [[pair_text(row), _number(row.distance_mm, 2), confidence_text(row.confidence)]
                                for row in shown])
