"""The acquisition screen: both feeds with the probe overlay, stream health, IMU plot, trocar tip, Store SN, nodes.

Why: the technician's one view while stored nodes are collected, read at a glance at 1024x700 as at 1920x1080: the
tip position, the endoscope angles and the store spread are large numbers (the spread green within the store limit,
red beyond), status lines word-wrap and are never cut (:mod:`snreg_gui.acquisition.status`), the feeds keep the camera's
shape (:mod:`snreg_gui.acquisition.live_view`) and the side column is a splitter pane that scrolls rather than grow
the window. The label and counts typed for a node are cleared once it is stored: the next node is another station. It only displays what the
:class:`AcquisitionWorker` emits and forwards requests (store, undo, window size, spread limit) back to it; nothing
is computed here. Auto-store only presses Store SN for the technician when the worker says its rule holds.

Store SN (button, Space, F5 alike) stays pressable while frames arrive: the core decides, and a refusal comes back
in words (red, with a beep for a foot pedal that cannot see the screen) and goes on record in the session; the
ready line says beforehand what a press would meet (:mod:`snreg_gui.acquisition.store_prompts`). A store near a
stored node asks first, naming it; a refusal the operator may override (the camera's insertion lost after the camera
moved) asks whether to store anyway, and the override goes on record. Auto-store never overrides. Beside the IMU
angles, the camera's insertion (:mod:`snreg_gui.acquisition.insertion_line`). Below Store SN (so that its buttons
never move when they come and go), the SPECT nodes not found yet with their expected errors if registered now, and
which error source to improve (:mod:`snreg_gui.acquisition.expected`). Beside Store SN, Store landmark with its name
picker (:mod:`snreg_gui.acquisition.landmark_store`), through the same guards and questions.
While a calibration wizard holds the cameras the screen says "paused for calibration", not that the feed died.
"""

from __future__ import annotations

import math
import time

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtGui import QKeySequence, QShortcut
from PySide6.QtWidgets import (QApplication, QCheckBox, QDoubleSpinBox, QFormLayout, QFrame, QGroupBox,
                               QHBoxLayout, QLabel, QLineEdit, QMessageBox, QPushButton, QScrollArea, QSpinBox,
                               QSplitter, QVBoxLayout, QWidget)

from snreg.imu.monitor import ImuMonitor
from snreg.workflow.acquisition import THESIS_FIXES_PER_NODE, StoreLimits
from snreg_gui.acquisition.expected import ExpectedErrors
from snreg_gui.acquisition.health import camera_health, imu_health
from snreg_gui.acquisition.insertion_line import InsertionLine
from snreg_gui.acquisition.landmark_store import LandmarkPicker, LandmarkStoring, is_landmark, near_title, store_what
from snreg_gui.acquisition.live_view import LiveView, plot_pane
from snreg_gui.acquisition.node_table import StoredNodes
from snreg_gui.acquisition.orientation_plot import ANGLE_COLOURS, OrientationPlot
from snreg_gui.acquisition.status import BAD, GOOD, WARN, BigNumber, StatusLine, ValueRow, set_style, spread_colour
from snreg_gui.acquisition.store_prompts import near_node_box, override_box, ready_line
from snreg_gui.acquisition.worker import FrameResult, StoreRequest
from snreg_gui.common.feed_view import FeedView
from snreg_gui.common.splitters import first_width

STORE_SHORTCUTS = ("Space", "F5")        # F5: what a USB foot pedal is usually set to send
UNDO_SHORTCUT = "Ctrl+Z"
DRAW_INTERVAL_MS = 33        # the feeds are drawn at most at 30 Hz, the newest frame only
LABEL_HINT = "station, e.g. OBT R"
PAUSED_TEXT = "paused for calibration (a wizard has the cameras)"


def _row(*parts) -> QHBoxLayout:
    """A row of widgets; a (widget, stretch) pair gives that widget a stretch factor, an int is a stretchable space."""
    row = QHBoxLayout()
    for part in parts:
        if isinstance(part, int):
            row.addStretch(part)
        else:
            row.addWidget(*part) if isinstance(part, tuple) else row.addWidget(part)
    return row


class AcquisitionScreen(LandmarkStoring, QWidget):
    """Emits ``store_requested(StoreRequest)``, ``undo_requested()``, ``fixes_per_node_changed(int)`` and
    ``max_spread_changed(float)``; fed by :meth:`show_result`, :meth:`add_node`, :meth:`remove_node`,
    :meth:`show_store_problem`, :meth:`ask_to_confirm`, :meth:`offer_override` and :meth:`set_paused`.
    ``confirm_box``: the question a press asked, while it is open. ``preparing``: a callable that says what the rig is
    still preparing (the demo's tour rendering), shown on the camera line."""

    store_requested = Signal(object)
    undo_requested = Signal()
    fixes_per_node_changed = Signal(int)
    max_spread_changed = Signal(float)

    def __init__(self, imu: ImuMonitor, fixes_per_node: int = THESIS_FIXES_PER_NODE,
                 max_spread_mm: float = StoreLimits.max_spread_mm, untracked: str = "camera insertion not tracked",
                 error_sources: dict | None = None, preparing=None):
        super().__init__()
        self._imu = imu
        self._preparing = preparing or str         # what the rig is still preparing, in words ("": nothing)
        self._last_result: FrameResult | None = None
        self._last_arrival_ns: int | None = None
        self._store_pending = False
        self._overriding = False             # the store pending is the operator's "Store anyway"
        self._paused = ""
        self._stopped = ""                   # why the feed stopped, once it has
        self.confirm_box: QMessageBox | None = None
        self.left_feed, self.right_feed = FeedView("left"), FeedView("right")
        self.orientation = OrientationPlot()
        self.angles = ValueRow(("yaw", "pitch", "roll"), "-888.8", tuple(ANGLE_COLOURS.values()), columns=1)
        self.angles.setToolTip("endoscope orientation from the IMU, degrees (yaw about z, pitch about y, roll about x)")
        self.insertion_line = InsertionLine(untracked)
        self.tip_values = ValueRow(("x", "y", "z"), "-8888.8")
        self.tip_values.setToolTip("the probe tip in the trocar frame, mm")
        self.tip_trocar = StatusLine("no fix yet", 1)
        self.spread_value = BigNumber("88.88")
        self.spread_value.setToolTip("how far the fixes of the store window spread about their median: within the "
                                     "spread limit (green) Store SN stores, beyond it (red) it refuses")
        self.video_health, self.imu_health = StatusLine("camera: waiting", 2), StatusLine("", 1)
        self.link_health = StatusLine("", 1)            # the live link to 3D Slicer, shown while it is on
        self.link_health.setVisible(False)
        self.expected = ExpectedErrors(error_sources)
        self.missing_list, self.guidance = self.expected.missing_list, self.expected.guidance
        self.store_button = QPushButton("Store SN")
        self.store_button.setMinimumHeight(self.store_button.sizeHint().height() * 4 // 3)
        self.store_reason = StatusLine("", 2)      # the insertion's refusal runs long: it takes more lines
        self.store_status = StatusLine("", 2)
        self.undo_button = QPushButton("Undo last")
        self.undo_button.setEnabled(False)
        self.undo_button.setToolTip(f"take back the node stored last ({UNDO_SHORTCUT}); the journal keeps it on record")
        self.auto_store = QCheckBox("auto-store")      # beside the fixes: the row Store landmark took fits 700 px
        self.auto_store.setToolTip("auto-store when the probe is held still, away from every stored node")
        self.label_edit = QLineEdit()
        self.label_edit.setPlaceholderText(LABEL_HINT)
        self.label_edit.setToolTip("the station of the next node; cleared after each store")
        self.counts_edit = QLineEdit()
        self.counts_edit.setPlaceholderText("optional")
        self.counts_edit.setToolTip("gamma counts of the next node (optional); cleared after each store")
        self.fixes_spin = QSpinBox()
        self.fixes_spin.setRange(1, 600)
        self.fixes_spin.setValue(fixes_per_node)
        self.spread_spin = QDoubleSpinBox(decimals=1, minimum=0.1, maximum=50.0, singleStep=0.5, suffix=" mm")
        self.spread_spin.setValue(max_spread_mm)
        self.spread_spin.setToolTip("a store whose fixes spread more than this is refused (the probe moved)")
        self.nodes = StoredNodes()
        self.landmark_picker = LandmarkPicker()
        self._layout()
        self.landmark_picker.requested.connect(self.request_landmark)
        self.store_button.clicked.connect(lambda: self.request_store("button"))
        for key in STORE_SHORTCUTS:
            QShortcut(QKeySequence(key), self, activated=lambda key=key: self.request_store(key))
        self.spread_spin.valueChanged.connect(self.max_spread_changed)
        self.spread_spin.valueChanged.connect(lambda _: self._show_spread())
        self.undo_button.clicked.connect(self.request_undo)
        QShortcut(QKeySequence(UNDO_SHORTCUT), self, activated=self.request_undo)
        self.fixes_spin.valueChanged.connect(self.fixes_per_node_changed)
        self.fixes_spin.valueChanged.connect(lambda _: self._update_store_state())
        self._health_timer = QTimer(self, interval=250, timeout=self._show_health)
        self._health_timer.start()
        self._undrawn: FrameResult | None = None
        self._draw_timer = QTimer(self, interval=DRAW_INTERVAL_MS, timeout=self._draw)
        self._draw_timer.start()
        self._store_state: tuple | None = None     # (enabled, reason, style) shown now
        self._set_store_enabled(False, "waiting for the first frame")

    def _layout(self) -> None:
        plot = plot_pane(self.orientation, self.angles, self.insertion_line)
        self.live = LiveView(self.left_feed, self.right_feed, plot)
        self.live.arranged.connect(lambda arrangement: self.angles.set_columns(0 if arrangement.stacked else 1))
        column_widget = QWidget()
        column = QVBoxLayout(column_widget)
        column.setContentsMargins(0, 0, 0, 0)
        for widget in (self._live_box(), self._store_box(), self.expected, self.nodes):
            column.addWidget(widget)
        column.setStretch(3, 1)
        side = QScrollArea()         # on a screen lower than 700 px it scrolls, rather than grow the window off screen
        side.setWidget(column_widget)
        side.setWidgetResizable(True)
        side.setFrameShape(QFrame.Shape.NoFrame)
        side.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        side.setMinimumWidth(column_widget.minimumSizeHint().width() + side.verticalScrollBar().sizeHint().width())
        self.splitter = QSplitter(Qt.Orientation.Horizontal)
        self.splitter.addWidget(self.live)
        self.splitter.addWidget(side)
        self.splitter.setChildrenCollapsible(False)
        self.splitter.setStretchFactor(0, 3)
        self.splitter.setStretchFactor(1, 1)
        first_width(self.splitter, 1, lambda total: max(side.minimumWidth(), total // 4))
        QVBoxLayout(self).addWidget(self.splitter)

    def _live_box(self) -> QGroupBox:
        box = QGroupBox("Probe tip (trocar frame, mm) and streams")
        column = QVBoxLayout(box)
        column.setSpacing(2)                   # status lines close together: the side column fits 700 px high
        column.addWidget(self.tip_values, 0, Qt.AlignmentFlag.AlignLeft)
        for widget in (self.tip_trocar, self.video_health, self.imu_health, self.link_health):
            column.addWidget(widget)
        return box

    def _store_box(self) -> QGroupBox:
        box = QGroupBox("Store SN")
        form = QFormLayout(box)
        form.setFieldGrowthPolicy(QFormLayout.FieldGrowthPolicy.AllNonFixedFieldsGrow)
        form.setVerticalSpacing(4)
        form.addRow("label", _row((self.label_edit, 3), QLabel(" counts"), (self.counts_edit, 2)))
        form.addRow("spread", _row(self.spread_value, 1, QLabel("limit"), self.spread_spin))
        form.addRow("fixes per node", _row(self.fixes_spin, 1, self.auto_store))
        form.addRow(_row((self.store_button, 2), (self.undo_button, 1)))
        form.addRow("landmark", self.landmark_picker)
        form.addRow(self.store_reason)
        form.addRow(self.store_status)
        return box

    # -- from the worker -----------------------------------------------------
    def show_result(self, result: FrameResult) -> None:
        """Take one processed frame pair: store state and auto-store now, pictures at the next display tick."""
        self._last_result, self._last_arrival_ns = result, time.perf_counter_ns()
        self._undrawn = result
        self.orientation.append((math.nan,) * 3 if result.imu.stale else result.imu.euler_deg)   # silent: a gap
        self._update_store_state()
        self._show_spread()                  # with the ready line, so both say the same spread
        outcome = result.outcome
        if self.auto_store.isChecked() and outcome.auto_store_due and self.store_button.isEnabled():
            self.request_store("auto")

    def _draw(self) -> None:
        """Draw the newest result, if any came since the last tick; older ones are skipped, so a slow paint
        never builds a backlog of frames on the GUI thread. The IMU plot redraws at its own rate, frames or not."""
        self.orientation.redraw_due(time.perf_counter())
        result, self._undrawn = self._undrawn, None
        if result is None:
            return
        outcome = result.outcome
        depth = float(outcome.fix.tip[2]) if outcome.fix is not None else None
        self.left_feed.show_frame(result.left_rgb, result.overlay_left, depth)
        self.right_feed.show_frame(result.right_rgb, result.overlay_right, depth)
        self.left_feed.show_hot_spots(result.hot_spots_left)
        self.right_feed.show_hot_spots(result.hot_spots_right)
        if result.left_rgb.shape[1]:
            self.live.set_aspect(result.left_rgb.shape[0] / result.left_rgb.shape[1])
        self.angles.show_values(result.imu.euler_deg, stale=result.imu.stale)   # greyed: the IMU went silent
        self.insertion_line.show_outcome(outcome)
        self.expected.show_guidance(result.guidance)
        self.tip_values.show_values(outcome.tip_trocar)
        self.tip_trocar.setText("tracked" if outcome.tip_trocar is not None else f"no fix ({outcome.reason})")

    def _show_spread(self) -> None:
        """The store window's spread, coloured against the store guard's limit (the spread limit set here, which the
        worker refuses by); a dash while the window is not full."""
        spread = self._last_result.outcome.window_spread_mm if self._last_result is not None else math.nan
        self.spread_value.show_value(spread, 2)
        self.spread_value.set_colour(spread_colour(spread, self.spread_spin.value()))

    def show_missing(self, missing: list) -> None:
        """The SPECT nodes the latest registration left unpaired, with their expected errors
        (:meth:`~snreg_gui.acquisition.expected.ExpectedErrors.show_missing`)."""
        self.expected.show_missing(missing)

    def add_error_sources(self, node_id: str, sources: dict) -> None:
        """A stored node's covariance by source, for the advice on which error source to improve."""
        self.expected.add_error_sources(node_id, sources)

    def _node_ids(self) -> list[str]:
        return [self.nodes.item(row, 0).text() for row in range(self.nodes.rowCount())]

    def set_nodes(self, nodes) -> None:
        """Show the nodes already in the session (a continued session); replaces the table."""
        self.nodes.setRowCount(0)
        for node in nodes:
            self.nodes.append(node)
        self.undo_button.setEnabled(self.nodes.rowCount() > 0)
        self.expected.set_node_ids(self._node_ids())

    def add_node(self, node) -> None:
        """Append a stored node (an :class:`~snreg.session.IntraopNode`) to the table; the label and counts typed for
        it are cleared (the next node is another station), and the empty field says what the last one was."""
        if is_landmark(node):
            return self._add_landmark(node)
        self._store_pending = False
        self.nodes.append(node)
        self.expected.set_node_ids(self._node_ids())
        self.undo_button.setEnabled(True)
        if self.label_edit.text().strip() == node.label:       # not what was typed meanwhile for the next node
            self.label_edit.clear()
            self.counts_edit.clear()
        self.label_edit.setPlaceholderText(f"{LABEL_HINT} ({node.id} was '{node.label}')" if node.label
                                           else LABEL_HINT)
        anyway = " anyway, the override on record" if self._overriding else ""
        self._overriding = False
        self._say(f"stored {node.id}{f' {node.label!r}' if node.label else ''}{anyway} (spread {node.spread_mm:.2f} mm "
                  f"over {node.n_frames} fixes)", GOOD)
        self._update_store_state()

    def remove_node(self, node) -> None:
        """Drop an undone node from the table (and from the advice)."""
        self.nodes.remove(node.id)
        self.expected.set_node_ids(self._node_ids())
        self.undo_button.setEnabled(self.nodes.rowCount() > 0)
        self._say(f"undone: {node.id} (kept on record in the session journal)", "")

    def show_link_state(self, text: str) -> None:
        """The live link's clients and address (from its ``state_changed`` signal); empty hides the line."""
        self.link_health.setText(text)
        self.link_health.setToolTip(text)
        self.link_health.setVisible(bool(text))

    def show_store_problem(self, message: str) -> None:
        """A store refused or failed: the reason in red, and a beep (a foot pedal does not look at the screen)."""
        self._store_pending = self._overriding = False
        self._say(message, BAD)
        QApplication.beep()
        self._update_store_state()

    def ask_to_confirm(self, question: str, request: StoreRequest) -> None:
        """A store near a stored node: ask (the question names it); yes sends the request again, confirmed."""
        self._store_pending = False
        self._update_store_state()
        box = near_node_box(self, question, near_title(request))
        box.finished.connect(lambda answer: self._answered(answer == QMessageBox.StandardButton.Yes, request.confirm(),
                                                           "a node so close to a stored one"))
        self.confirm_box = box
        box.open()

    def offer_override(self, refusal: str, request: StoreRequest) -> None:
        """A refusal the operator may override (the camera's insertion lost after the camera moved): said in red with
        a beep, then asked; "Store anyway" sends the request again, overriding (the core keeps it on record)."""
        self.show_store_problem(f"Refused ({request.trigger}): the camera's insertion is lost; store anyway or not?")
        box, store_anyway = override_box(self, refusal, request.trigger, store_what(request))
        box.finished.connect(lambda _: self._answered(box.clickedButton() is store_anyway, request.overriding(),
                                                      "while the camera's insertion is lost"))
        self.confirm_box = box
        box.open()

    def _answered(self, yes: bool, request: StoreRequest, declined: str) -> None:
        """The question's answer: yes sends ``request``; no says it was not stored (``declined``: what not)."""
        self.confirm_box = None
        if yes:
            self._overriding = request.override
            self._store_pending = True
            self._set_store_enabled(False, "storing...")
            self.store_requested.emit(request)
        else:
            self._say(f"Not stored: you chose not to store {declined}.", WARN)

    def show_source_stopped(self, problem: str) -> None:
        """The feed ended or was lost (a replay played to its end, a camera unplugged): say why instead of "stale"."""
        self._stopped = problem

    def set_paused(self, paused: bool) -> None:
        """Say "paused for calibration" (a wizard holds the cameras) instead of a stale feed; Store SN waits."""
        self._paused = PAUSED_TEXT if paused else ""
        self._show_health()
        self._update_store_state()

    # -- Store SN ------------------------------------------------------------
    def request_store(self, trigger: str = "button") -> None:
        """Ask the worker to store (``trigger``: "button", "Space", "F5" or "auto"); when nothing can be asked now
        (no frames, paused, a store pending) say so in red."""
        if not self.store_button.isEnabled():
            if trigger != "auto":
                self.show_store_problem(f"Not stored ({trigger}): {self.store_button.toolTip()}.")
            return
        counts = self.counts_edit.text().strip()
        try:
            counts_value = float(counts) if counts else float("nan")
        except ValueError:
            self._say("Gamma counts must be a number; correct it or leave it empty.", BAD)
            return
        self._store_pending = True
        self._set_store_enabled(False, "storing...")
        self.store_requested.emit(StoreRequest(self.label_edit.text().strip(), counts_value, trigger))

    def _say(self, text: str, style: str) -> None:
        self.store_status.setText(text)
        self.store_status.setToolTip(text)
        set_style(self.store_status, style)

    def request_undo(self) -> None:
        if self.undo_button.isEnabled():
            self.undo_requested.emit()

    def _update_store_state(self) -> None:
        line = ready_line(self._last_result.outcome if self._last_result else None, self.fixes_spin.value(),
                          paused=bool(self._paused), pending=self._store_pending, feed_age_s=self._feed_age_s(),
                          stopped=self._stopped)
        self._set_store_enabled(line.enabled, line.text, line.style)

    def _set_store_enabled(self, enabled: bool, reason: str, style: str = "") -> None:
        """Store SN's state, its reason and the reason's tone; the widgets are touched only when one of them changed
        (this runs for every pair, and mostly says what it said already)."""
        state = (enabled, reason, style)
        if state == self._store_state:
            return
        self._store_state = state
        self.store_button.setEnabled(enabled)
        self.landmark_picker.button.setEnabled(enabled)
        self.store_button.setToolTip(reason)
        self.store_reason.setText(reason)          # its tooltip with it
        set_style(self.store_reason, style)

    # -- health --------------------------------------------------------------
    def _feed_age_s(self) -> float:
        return (time.perf_counter_ns() - self._last_arrival_ns) / 1e9 if self._last_arrival_ns else float("inf")

    def _show_health(self) -> None:
        if self._last_result is not None:
            self._update_store_state()           # a feed that stopped disables Store SN
        for line, (text, style) in ((self.video_health, camera_health(self._last_result, self._feed_age_s(),
                                                                      self._paused, self._preparing())),
                                    (self.imu_health, imu_health(self._imu.snapshot()))):
            line.setText(text)
            set_style(line, style)
