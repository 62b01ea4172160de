"""The offline review screen: what a saved session recorded, when, and how well.

Why: a research engineer reviews a session after the fact: its header and calibration, the IMU angles,
probe tip, the camera's insertion, tracking quality and frame rate on one time axis with the stored nodes marked,
each node's snapshots, and the stored registrations. Reading and fusing run in workers
(:func:`snreg.session.timeline.load_review`, then :func:`~snreg.session.timeline.fuse_imu_blocks`,
whose blocks are drawn as they come), so an hour-long session never blocks the GUI; the file is
closed once read, so it can be opened elsewhere while it is shown. A session still being recorded (by this app
or another) is readable while it is written: Refresh reads it again to show what was added since. The session this app
records is followed (:meth:`ReviewScreen.follow`): shown read-only and read again after each store or registration
(:meth:`ReviewScreen.live_changed`) while the tab is visible, else when it is next shown. The preop set stored with the
session (nodes, landmarks, patient position and down) has a tab beside the stored nodes; a registration's pairs are
shown only once one is chosen; ``session_read`` hands the session as read (closed) to whoever shows it elsewhere (the
window's Registration tab, when nothing is recorded).

>>> screen = ReviewScreen()
>>> screen.loaded.connect(lambda path: ...)      # everything is shown
>>> screen.failed.connect(status_bar.showMessage)  # one sentence: corrupt, foreign or missing file
>>> screen.load("session.h5")
"""

from __future__ import annotations

import time
from pathlib import Path

from PySide6.QtCore import QCoreApplication, Qt, Signal
from PySide6.QtWidgets import (QGroupBox, QHBoxLayout, QLabel, QPushButton, QSplitter, QTabWidget, QVBoxLayout,
                               QWidget)

from snreg.session import SessionError, set_final_in_file
from snreg.session.timeline import SessionReview, fuse_imu_blocks, load_review
from snreg_gui.common.workers import Worker
from snreg_gui.review.panels import (PREOP_COLUMNS, SnapshotPair, StoredRegistrations, fill_node_table, fill_table,
                                     header_text, node_table, preop_rows, preop_text, read_only_table)
from snreg_gui.review.timelines import TimelinePlots
from snreg_gui.review.video_view import VideoScrubber


class ReviewScreen(QWidget):
    """Shows one session file at a time; :meth:`load` starts reading it in a worker.

    Signals: ``loaded(path)`` once everything is shown, ``failed(sentence)`` when the file cannot be read
    (the sentence is also shown in the screen). A :meth:`load` while another is running supersedes it.
    ``node_table`` lists the stored nodes and, in italics as "landmark: <name>", the stored landmarks (never counted as
    nodes), in the order stored; selecting one puts the cursor at its time, shades its store window and shows
    the recorded pair there (its snapshots when the session has no video); dragging the cursor or clicking a plot
    shows the pair of that moment with the probe overlay as tracked then.
    """

    loaded = Signal(str)
    failed = Signal(str)
    final_changed = Signal(object)      # the registration now marked final in the file shown (None: none)
    session_read = Signal(object)       # the session as read (closed, read-only), once its contents are shown

    def __init__(self, parent=None):
        super().__init__(parent)
        self.status = QLabel("no session loaded")
        self.status.setWordWrap(True)
        self.refresh_button = QPushButton("Refresh")
        self.refresh_button.setToolTip("read the session file again: a session still being recorded shows what "
                                       "was stored since")
        self.refresh_button.setEnabled(False)
        self.refresh_button.clicked.connect(self.refresh)
        self.header = QLabel("")
        self.header.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.header.setWordWrap(True)                 # a damage line is long: it must not widen the window
        self.node_table = node_table()
        self.preop_caption = QLabel("")
        self.preop_caption.setWordWrap(True)
        self.preop_table = read_only_table(PREOP_COLUMNS)
        self.node_tabs = QTabWidget()
        self.snapshots = SnapshotPair()
        self.registrations = StoredRegistrations()
        self.timelines = TimelinePlots()
        self.scrubber = VideoScrubber()
        self._layout()
        self.node_table.itemSelectionChanged.connect(self._show_selected_node)
        self.timelines.cursor_moved.connect(self.scrubber.show_at)
        self.scrubber.frame_ready.connect(self.snapshots.show_video_frame)
        self._review: SessionReview | None = None
        self._worker: Worker | None = None          # the one loader or fuser running
        self._pending: str | None = None            # a path asked for while a worker was running
        self._path = ""
        self._fuse_next = False
        self._failed = False
        self._stopped = False                       # closing: start nothing more
        self._live = ""                             # the session being recorded, followed while it is the one shown
        self._stale = False                         # the live session changed while the screen was hidden
        self._chosen: int | None = None             # the registration chosen before the file was read again
        self.recording_session = lambda: None       # the window's session being recorded (marks go through it)
        self.registrations.final_requested.connect(self._mark_final)
        QCoreApplication.instance().aboutToQuit.connect(self.shutdown)

    def _layout(self) -> None:
        preop = QWidget()                             # beside the stored nodes, one tab each: no taller window
        preop_layout = QVBoxLayout(preop)
        preop_layout.setContentsMargins(0, 0, 0, 0)
        self.preop_table.setMinimumHeight(40)        # with its caption, no taller than the stored nodes' table
        preop_layout.addWidget(self.preop_caption)
        preop_layout.addWidget(self.preop_table)
        self.node_tabs.addTab(self.node_table, "stored nodes")
        self.node_tabs.addTab(preop, "preop nodes")
        registrations = QGroupBox("registrations")
        QVBoxLayout(registrations).addWidget(self.registrations)
        side = QSplitter(Qt.Orientation.Vertical)
        for widget in (self.node_tabs, self.snapshots, registrations):
            side.addWidget(widget)
        side.setSizes([300, 300, 250])               # proportions; the user moves the handles
        plots = QWidget()                             # the timelines, the landmarks' legend under them
        plots_layout = QVBoxLayout(plots)
        plots_layout.setContentsMargins(0, 0, 0, 0)
        plots_layout.addWidget(self.timelines, stretch=1)
        plots_layout.addWidget(self.timelines.legend)
        body = QSplitter(Qt.Orientation.Horizontal)
        body.addWidget(side)
        body.addWidget(plots)
        body.setSizes([600, 900])
        layout = QVBoxLayout(self)
        top = QHBoxLayout()
        top.addWidget(self.status, 1)
        top.addWidget(self.refresh_button)
        layout.addLayout(top)
        layout.addWidget(self.header)
        layout.addWidget(body, stretch=1)

    # -- loading ---------------------------------------------------------------
    @property
    def path(self) -> str:
        """The session file shown or being read ("" before the first :meth:`load`)."""
        return self._pending or self._path

    def load(self, path) -> None:
        """Read the session at ``path`` in a worker; ``loaded`` or ``failed`` tells how it went."""
        self.refresh_button.setEnabled(True)
        self._pending, self._stopped = str(path), False
        self.status.setText(f"loading {self._pending} ...")
        if self._worker is None:
            self._start_pending()
        else:
            self._worker.quit()                      # a fusion stops after its block; a read runs out, ignored

    def refresh(self) -> None:
        """Read the file shown again (a session still being recorded has more in it by now)."""
        self._stale = False
        if self.path:
            self.load(self.path)

    # -- the session being recorded ----------------------------------------------
    def follow(self, path) -> None:
        """Show the session being recorded at ``path`` (read-only), read again by :meth:`live_changed`; read now when
        the screen is visible, else when it is next shown (reading an hour of streams costs the recording CPU)."""
        self._live = str(path)
        if self.isVisible() or self._worker is not None:
            self.load(self._live)
            return
        self._path, self._review, self._stale = self._live, None, True
        self._clear()
        self.refresh_button.setEnabled(True)
        self.status.setText(f"recording into {self._live}: shown, read-only, when this tab is opened")

    def live_changed(self) -> None:
        """The session being recorded changed (a node stored or removed, a registration stored): read it again when
        it is the one shown, now if visible, else when next shown."""
        if not self._live or self.path != self._live:
            return
        if self.isVisible():
            self.refresh()
        else:
            self._stale = True

    @property
    def following(self) -> bool:
        """The screen shows the session being recorded."""
        return bool(self._live) and self.path == self._live

    def showEvent(self, event) -> None:
        super().showEvent(event)
        if self._stale and self.following:
            self.refresh()

    def _start_pending(self) -> None:
        self._chosen = self.registrations.chosen if self._pending == self._path else None
        self._path, self._pending = self._pending, None
        self._failed, self._fuse_next, self._review = False, False, None
        self._clear()
        self._run(Worker(load_review, self._path), returned=self._show_review)

    def _run(self, worker: Worker, *, returned=None, yielded=None) -> None:
        if returned is not None:
            worker.returned.connect(returned)
        if yielded is not None:
            worker.yielded.connect(yielded)
        worker.errored.connect(self._show_error)
        worker.finished.connect(self._worker_finished)
        self._worker = worker
        worker.start()

    def _show_review(self, review: SessionReview) -> None:
        if self._pending is not None:
            return
        self._review = review
        self.header.setText(header_text(review))
        fill_node_table(self.node_table, review.stored)
        self.preop_caption.setText(preop_text(review))
        fill_table(self.preop_table, preop_rows(review))
        self.node_tabs.setTabText(1, f"preop nodes ({0 if review.preop is None else len(review.preop)})")
        self.registrations.show_registrations(review.registrations)
        if self._chosen is not None:                  # read again (Refresh, the live session): the same one chosen
            self.registrations.choose(self._chosen)
        if review.session is not None:
            self.session_read.emit(review.session)
        self.timelines.show_review(review)
        self.scrubber.load(review.path, review.t0_ns)
        self._fuse_next = len(review.imu.t_s) > 0
        if self._fuse_next:
            self.status.setText(f"fusing {len(review.imu.t_s)} IMU samples ...")

    def _add_imu_block(self, euler_deg) -> None:
        if self._pending is not None:
            return
        self.timelines.add_imu_block(euler_deg)
        done = self.timelines.imu_shown / max(len(self._review.imu.t_s), 1)
        self.status.setText(f"fusing IMU samples: {done:.0%}")

    def _show_error(self, sentence: str) -> None:
        if self._pending is not None:
            return
        self._failed = True
        self.status.setText(sentence)
        self.failed.emit(sentence)

    def _worker_finished(self) -> None:
        self._worker.wait()                         # its thread ends right after ``finished``
        self._worker = None
        if self._pending is not None:
            self._start_pending()
        elif self._stopped:
            return
        elif self._fuse_next and not self._failed:
            self._fuse_next = False
            self._run(Worker(fuse_imu_blocks, self._review.imu), yielded=self._add_imu_block)
        elif not self._failed:
            nodes, registrations = len(self._review.nodes), len(self._review.registrations)
            marks = len(self._review.landmarks)
            landmarks = f"{marks} landmark{'' if marks == 1 else 's'}, " if marks else ""
            where = (f"{self._path} (being recorded: shown read-only, read again as nodes are stored)"
                     if self.following else self._path)
            self.status.setText(f"{where}: {nodes} stored node{'' if nodes == 1 else 's'}, {landmarks}"
                                f"{registrations} registration{'' if registrations == 1 else 's'} (as read at "
                                f"{time.strftime('%H:%M:%S')}; Refresh reads it again)")
            self.scrubber.when_opened(lambda path=self._path: self._announce(path))

    def _announce(self, path: str) -> None:
        """Everything is shown and the file closed (the video's index read too): ``loaded``, unless another load
        began meanwhile."""
        if self._pending is None and path == self._path:
            self.loaded.emit(path)

    def _clear(self) -> None:
        self.header.setText("")
        fill_node_table(self.node_table, [])
        self.preop_caption.setText("")
        fill_table(self.preop_table, [])
        self.snapshots.show_pair(None, None)
        self.scrubber.close()
        self.registrations.show_registrations([])
        self.timelines.clear_review()

    # -- final mark ------------------------------------------------------------
    def _mark_final(self, n) -> None:
        """Mark registration ``n`` final (None: unmark) in the file shown: through the window's session when it is
        the one being recorded (HDF5 allows one writer), else in the closed file; journal line and attribute only."""
        if self._review is None:
            return
        session = self.recording_session()
        try:
            if session is not None and session.writable and Path(session.path).resolve() == Path(self._path).resolve():
                session.set_final_registration(n)
            else:
                set_final_in_file(self._path, n)
        except SessionError as err:
            self.status.setText(str(err))
            return
        self.registrations.show_final(n)
        self.status.setText(f"{self._path}: " + ("no registration is marked final" if n is None else
                                                 f"registration {n} is marked final; the exports use it"))
        self.final_changed.emit(n)

    # -- selection -------------------------------------------------------------
    def _show_selected_node(self) -> None:
        rows = self.node_table.selectionModel().selectedRows()
        if not rows or self._review is None:
            return
        node = self._review.stored[rows[0].row()]
        self.timelines.set_cursor(node.t_s)
        window = self._store_window(node)
        self.timelines.show_window(*window)
        if self.scrubber.video is not None:           # the recorded pair at its store, with the overlay of then
            self.scrubber.show_at(node.t_s)
        else:
            self.snapshots.show_pair(node.left_rgb, node.right_rgb)

    def _store_window(self, node) -> tuple[float | None, float | None]:
        """From the first to the last fix the node was the median of (its probe rows up to its time)."""
        fixes = self._review.probe.t_s
        before = fixes[fixes <= node.t_s + 1e-9]
        if not len(before) or node.n_frames < 1:
            return None, None
        return float(before[-min(node.n_frames, len(before))]), float(node.t_s)

    # -- shutdown --------------------------------------------------------------
    def shutdown(self) -> None:
        """Stop a running fusion and wait for its thread (a read cannot be interrupted; it ends by itself).

        Called on closing and when the application quits; safe to call twice; a later :meth:`load` works again."""
        self._pending, self._stopped = None, True
        if self._worker is not None:
            self._worker.quit()
            self._worker.wait()
        self.scrubber.close()

    def closeEvent(self, event) -> None:
        self.shutdown()
        super().closeEvent(event)
