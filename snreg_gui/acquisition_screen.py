"""The acquisition screen: both feeds with the probe overlay, stream health, IMU plot, trocar tip, Store SN, nodes.

Why: the technician's one view while stored nodes are collected. It only displays what the
:class:`AcquisitionWorker` emits and forwards requests back to it; nothing is computed here.
"""

from __future__ import annotations

import time

from PySide6.QtCore import QTimer, Signal
from PySide6.QtGui import QKeySequence, QShortcut
from PySide6.QtWidgets import (QFormLayout, QGridLayout, QGroupBox, QHBoxLayout, QLabel, QLineEdit, QPushButton,
                               QSpinBox, QTableWidget, QTableWidgetItem, QVBoxLayout, QWidget)

from snreg_gui.acquisition_worker import THESIS_FIXES_PER_NODE, FrameResult, StoreRequest
from snreg_gui.feed_view import FeedView
from snreg.imu.monitor import STALE_AFTER_S, ImuMonitor
from snreg_gui.orientation_plot import OrientationPlot

STORE_SHORTCUTS = ("Space", "F5")        # F5: what a USB foot pedal is usually set to send
_NODE_COLUMNS = ("id", "label", "x", "y", "z", "spread mm", "frames")


class AcquisitionScreen(QWidget):
    """Emits ``store_requested(StoreRequest)`` and ``fixes_per_node_changed(int)``; fed by :meth:`show_result`."""

    store_requested = Signal(object)
    fixes_per_node_changed = Signal(int)

    def __init__(self, imu: ImuMonitor, fixes_per_node: int = THESIS_FIXES_PER_NODE):
        super().__init__()
        self._imu = imu
        self._last_result: FrameResult | None = None
        self._last_arrival_ns: int | None = None
        self.left_feed, self.right_feed = FeedView("left"), FeedView("right")
        self.orientation = OrientationPlot()
        self.video_health, self.imu_health = QLabel("video: waiting"), QLabel("IMU: waiting")
        self.tip_trocar = QLabel("tip (trocar): no fix")
        self.store_button = QPushButton("Store SN")
        self.store_reason = QLabel("waiting for the first frame")
        self.store_status = QLabel("")
        self.undo_button = QPushButton("Undo last node")
        self.undo_button.setEnabled(False)
        self.undo_button.setToolTip("Not available yet: the session file cannot remove a stored node.")
        self.label_edit = QLineEdit()
        self.label_edit.setPlaceholderText("station, e.g. OBT R")
        self.counts_edit = QLineEdit()
        self.counts_edit.setPlaceholderText("gamma counts (optional)")
        self.fixes_spin = QSpinBox()
        self.fixes_spin.setRange(1, 600)
        self.fixes_spin.setValue(fixes_per_node)
        self.nodes = QTableWidget(0, len(_NODE_COLUMNS))
        self.nodes.setHorizontalHeaderLabels(_NODE_COLUMNS)
        self._layout()
        self.store_button.clicked.connect(self.request_store)
        for key in STORE_SHORTCUTS:
            QShortcut(QKeySequence(key), self, activated=self.request_store)
        self.fixes_spin.valueChanged.connect(self.fixes_per_node_changed)
        self.fixes_spin.valueChanged.connect(lambda _: self._update_store_state())
        self._health_timer = QTimer(self, interval=250, timeout=self._show_health)
        self._health_timer.start()
        self._set_store_enabled(False, "waiting for the first frame")

    def _layout(self) -> None:
        feeds = QHBoxLayout()
        feeds.addWidget(self.left_feed)
        feeds.addWidget(self.right_feed)
        store = QGroupBox("Store SN")
        form = QFormLayout(store)
        form.addRow("label", self.label_edit)
        form.addRow("counts", self.counts_edit)
        form.addRow("fixes per node", self.fixes_spin)
        form.addRow(self.store_button)
        form.addRow(self.store_reason)
        form.addRow(self.store_status)
        form.addRow(self.undo_button)
        side = QVBoxLayout()
        for widget in (self.video_health, self.imu_health, self.tip_trocar, store, self.nodes):
            side.addWidget(widget)
        grid = QGridLayout(self)
        grid.addLayout(feeds, 0, 0)
        grid.addWidget(self.orientation, 1, 0)
        grid.addLayout(side, 0, 1, 2, 1)
        grid.setRowStretch(0, 3)
        grid.setRowStretch(1, 1)
        grid.setColumnStretch(0, 3)
        grid.setColumnStretch(1, 1)

    # -- from the worker -----------------------------------------------------
    def show_result(self, result: FrameResult) -> None:
        """Display one processed frame pair."""
        self._last_result, self._last_arrival_ns = result, time.perf_counter_ns()
        depth = float(result.fix.tip[2]) if result.fix is not None else None
        self.left_feed.show_frame(result.left_rgb, result.overlay_left, depth)
        self.right_feed.show_frame(result.right_rgb, result.overlay_right, depth)
        self.orientation.append(result.imu.euler_deg)
        if result.tip_trocar is None:
            self.tip_trocar.setText(f"tip (trocar): no fix ({result.reason})")
        else:
            x, y, z = result.tip_trocar
            self.tip_trocar.setText(f"tip (trocar): {x:7.1f} {y:7.1f} {z:7.1f} mm")
        self._update_store_state()

    def add_node(self, node) -> None:
        """Append a stored node (an :class:`~snreg.session.IntraopNode`) to the table."""
        row = self.nodes.rowCount()
        self.nodes.insertRow(row)
        cells = (node.id, node.label, *(f"{v:.1f}" for v in node.xyz_trocar), f"{node.spread_mm:.2f}", str(node.n_frames))
        for column, text in enumerate(cells):
            self.nodes.setItem(row, column, QTableWidgetItem(text))
        self.store_status.setText(f"stored {node.id} (spread {node.spread_mm:.2f} mm)")

    def show_store_problem(self, message: str) -> None:
        self.store_status.setText(message)

    # -- Store SN ------------------------------------------------------------
    def request_store(self) -> None:
        if not self.store_button.isEnabled():
            return
        counts = self.counts_edit.text().strip()
        try:
            counts_value = float(counts) if counts else float("nan")
        except ValueError:
            self.store_status.setText("Gamma counts must be a number; correct it or leave it empty.")
            return
        self.store_requested.emit(StoreRequest(f"SN{self.nodes.rowCount() + 1}", self.label_edit.text().strip(),
                                               self.fixes_spin.value(), counts_value))

    def _update_store_state(self) -> None:
        result, needed = self._last_result, self.fixes_spin.value()
        if result is None:
            self._set_store_enabled(False, "waiting for the first frame")
        elif result.fix is None:
            self._set_store_enabled(False, f"no valid fix: {result.reason}")
        elif result.valid_fixes < needed:
            self._set_store_enabled(False, f"collecting fixes: {result.valid_fixes} of {needed}")
        else:
            self._set_store_enabled(True, f"ready: median of the last {needed} fixes")

    def _set_store_enabled(self, enabled: bool, reason: str) -> None:
        self.store_button.setEnabled(enabled)
        self.store_button.setToolTip(reason)
        self.store_reason.setText(reason)

    # -- health --------------------------------------------------------------
    def _show_health(self) -> None:
        result = self._last_result
        if result is None:
            self.video_health.setText("video: waiting for frames")
        else:
            age_s = (time.perf_counter_ns() - self._last_arrival_ns) / 1e9
            stale = f"  STALE {age_s:.1f} s" if age_s > STALE_AFTER_S else ""
            self.video_health.setText(f"video: {result.fps:4.1f} fps, skew {result.skew_ms:+.1f} ms, "
                                      f"tracking {result.track_ms:.0f} ms{stale}")
        imu = self._imu.snapshot()
        stale = "  STALE" if imu.stale else ""
        problem = f" ({imu.problem})" if imu.problem else ""
        self.imu_health.setText(f"IMU: {imu.state}, {imu.rate_hz:.0f} Hz, {imu.corrupt} corrupt{stale}{problem}")
        self.video_health.setStyleSheet("color: red" if "STALE" in self.video_health.text() else "")
        self.imu_health.setStyleSheet("color: red" if imu.stale else "")
