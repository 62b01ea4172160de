"""The wizard's capture page: both live feeds with the found corners, Capture view, auto-capture, coverage.

Why: the technician needs to see, while moving the board, whether both eyes find it, whether the
current place is new, and where the image still lacks corners. The page only shows what the
:class:`~snreg.workflow.stereo_capture.LiveBoardFeed` worker found and asks :mod:`snreg.calibration.coverage`
what it means; a capture keeps the full-size grey images for the calibration.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QCheckBox, QGridLayout, QHBoxLayout, QLabel, QPushButton, QVBoxLayout, QWizardPage

from snreg.calibration.checkerboard import Board
from snreg.calibration.coverage import Coverage, coverage_map, is_still, similar_view
from snreg.calibration.stereo import MIN_VIEWS
from snreg.sources import FrameSource
from snreg.workflow.stereo_capture import LiveBoardFeed, LiveView
from snreg_gui.common.feed_view import FeedView
from snreg_gui.common.workers import Worker

STILL_FRAMES = 6                 # auto-capture once the board was found still in this many frames running
_HEAT_ALPHA = 120
_HEAT_LUT = pg.colormap.get("viridis").getLookupTable(0.0, 1.0, 256, alpha=False)   # (256, 3) RGB


def heat_rgba(counts: np.ndarray) -> np.ndarray:
    """(rows, cols, 4) RGBA of corner counts: transparent where none, then viridis, half see-through."""
    level = np.round(255.0 * counts / max(1, counts.max())).astype(int)
    rgba = np.zeros(counts.shape + (4,), np.uint8)
    rgba[..., :3] = _HEAT_LUT[level]
    rgba[..., 3] = np.where(counts > 0, _HEAT_ALPHA, 0)
    return rgba


@dataclass(frozen=True, eq=False)
class CapturedView:
    """One captured stereo view: full-size grey images and the live corners (full-size px) that steered it."""

    left_grey: np.ndarray
    right_grey: np.ndarray
    left_corners: np.ndarray
    right_corners: np.ndarray

    @property
    def stacked_corners(self) -> np.ndarray:
        """Both eyes' corners, (2 * cols * rows, 2): how views are compared."""
        return np.vstack([self.left_corners, self.right_corners])


class BoardFeedView(FeedView):
    """A feed with the found corners (corner 0 in red), a message when there are none, and the coverage heat map."""

    def __init__(self, title: str):
        super().__init__(title)
        self.heat_counts: np.ndarray | None = None

    def show_view(self, rgb: np.ndarray, corners: np.ndarray | None, message: str) -> None:
        """Show an RGB frame with ``corners`` (N, 2) in its pixels, or ``message`` when there are none."""
        self.show_frame(rgb)
        self.show_points(corners)
        self.show_message(message)

    def show_coverage(self, counts: np.ndarray) -> None:
        """Lay the (rows, cols) corner counts over the whole frame."""
        self.heat_counts = np.array(counts)
        self.show_heat(heat_rgba(self.heat_counts))


class CapturePage(QWizardPage):
    """Live feeds and the captured views (``views``, ``coverage``); complete with at least ``MIN_VIEWS`` views.

    ``latest_view`` is the last :class:`LiveView` shown (None before the first and after the feed stopped).

    ``board`` and ``target_views`` are asked of the setup page when the page is entered;
    ``run_worker`` starts a Worker and keeps it until the wizard shuts down.
    """

    def __init__(self, make_source: Callable[[], FrameSource], board: Callable[[], Board],
                 target_views: Callable[[], int], run_worker: Callable[[Worker], None]):
        super().__init__()
        self.setTitle("Capture views")
        self.setSubTitle("Hold the board still in a new place and tilt, with both eyes seeing all of it; "
                         "fill the coverage map, borders included.")
        self._make_source, self._board, self._target_views, self._run_worker = make_source, board, target_views, run_worker
        self.views: list[CapturedView] = []
        self.coverage: tuple[Coverage, Coverage] | None = None
        self._views_board: Board | None = None
        self._feed: LiveBoardFeed | None = None
        self.latest_view: LiveView | None = None
        self._recent: deque[np.ndarray | None] = deque(maxlen=STILL_FRAMES)
        self.left_view, self.right_view = BoardFeedView("left"), BoardFeedView("right")
        self.detection_label = QLabel("waiting for the first frame")
        self.feed_status = QLabel("")
        self.capture_button = QPushButton("Capture view")
        self.capture_reason = QLabel("")
        self.auto_capture = QCheckBox("Auto-capture when the board is held still in a new place")
        self.count_label = QLabel("")
        self.coverage_label = QLabel("coverage: no views yet")
        self.warning_label = QLabel("")
        self.warning_label.setStyleSheet("color: #c06000")
        self.feed_status.setStyleSheet("color: red")
        self._layout()
        self.capture_button.clicked.connect(self.capture)
        self._set_capture_enabled(False, "waiting for the first frame")

    def _layout(self) -> None:
        feeds = QHBoxLayout()
        feeds.addWidget(self.left_view)
        feeds.addWidget(self.right_view)
        controls = QGridLayout()
        controls.addWidget(self.capture_button, 0, 0)
        controls.addWidget(self.capture_reason, 0, 1)
        controls.addWidget(self.auto_capture, 1, 0, 1, 2)
        controls.addWidget(self.count_label, 2, 0)
        controls.addWidget(self.coverage_label, 2, 1)
        layout = QVBoxLayout(self)
        layout.addLayout(feeds, stretch=1)
        for widget in (self.detection_label, self.warning_label, self.feed_status):
            layout.addWidget(widget)
        layout.addLayout(controls)

    # -- wizard navigation ---------------------------------------------------------
    def initializePage(self) -> None:
        board = self._board()
        note = ""
        if self.views and board != self._views_board:
            note = (f" ({len(self.views)} views of the {self._views_board.cols}x{self._views_board.rows} board "
                    "were discarded: the board changed)")
            self.views.clear()
            self.coverage = None            # redrawn empty with the next frame
            self.completeChanged.emit()
        self._views_board = board
        self._show_progress(note)
        if self._feed is None:              # first entry, or the feed stopped: (re)open the source
            self._feed = LiveBoardFeed(self._make_source, board)
            worker = Worker(self._feed.frames)
            worker.yielded.connect(self.show_live_view, Qt.ConnectionType.QueuedConnection)
            worker.returned.connect(self.show_feed_end, Qt.ConnectionType.QueuedConnection)
            worker.errored.connect(self.show_feed_end, Qt.ConnectionType.QueuedConnection)
            self.feed_status.setText("")
            self.detection_label.setText("opening the camera feed ...")
            self._run_worker(worker)
        else:
            self._feed.board = board

    def isComplete(self) -> bool:
        return len(self.views) >= MIN_VIEWS

    def pause_feed(self, paused: bool) -> None:
        """Stop searching while another page is shown (the calibration wants the CPU), or go on."""
        if self._feed is not None:
            (self._feed.pause if paused else self._feed.resume)()

    def stop_feed(self) -> None:
        """Ask the frame loop to end (it closes the source); the wizard waits for its worker."""
        if self._feed is not None:
            self._feed.stop()

    # -- from the feed worker ------------------------------------------------------
    def show_live_view(self, view: LiveView) -> None:
        self.latest_view = view
        scale = view.display_scale
        left_message = "" if view.left_corners is not None else "board not found in left"
        right_message = "" if view.right_corners is not None else (
            "board not found in right" if view.left_corners is not None else "")
        self.left_view.show_view(view.left_rgb, None if view.left_corners is None else (view.left_corners + 0.5) * scale - 0.5,
                                 left_message)
        self.right_view.show_view(view.right_rgb, None if view.right_corners is None else (view.right_corners + 0.5) * scale - 0.5,
                                  right_message)
        if self.coverage is None:
            self._show_coverage(view.image_size)
        stacked = np.vstack([view.left_corners, view.right_corners]) if view.both_found else None
        self._recent.append(stacked)
        if stacked is None:
            reason = left_message or right_message
            self.detection_label.setText(reason)
            self.warning_label.setText("")
            self._set_capture_enabled(False, f"{reason}: show the whole board to both eyes")
            return
        self.detection_label.setText("board found in both eyes")
        similar = similar_view(stacked, [v.stacked_corners for v in self.views], view.image_size)
        self.warning_label.setText("" if similar is None else
                                   f"Too similar to view {similar + 1}: move or tilt the board to a new place.")
        self._set_capture_enabled(True, "ready" if similar is None else "ready, but the view adds little")
        if (self.auto_capture.isChecked() and similar is None and len(self.views) < self._target_views()
                and is_still(list(self._recent), view.image_size)):
            self.capture()

    def show_feed_end(self, problem: str | None) -> None:
        """The source ended or could not be opened: say why, in its own sentence (Back, then Next, reopens it)."""
        self.feed_status.setText(problem or "The camera feed stopped.")
        self.latest_view = None
        self._feed = None
        self._set_capture_enabled(False, "the camera feed has stopped")

    # -- capture -------------------------------------------------------------------
    def capture(self) -> None:
        """Keep the latest searched pair as a view (when both eyes found the board)."""
        view = self.latest_view
        if view is None or not view.both_found:
            return
        captured = CapturedView(view.left_grey, view.right_grey, view.left_corners, view.right_corners)
        similar = similar_view(captured.stacked_corners, [v.stacked_corners for v in self.views], view.image_size)
        self.views.append(captured)
        self._recent.clear()
        self.warning_label.setText("" if similar is None else
                                   f"View {len(self.views)} is much like view {similar + 1}; it adds little "
                                   "(drop it after calibrating if you like).")
        self._show_coverage(view.image_size)
        self._show_progress()
        self.completeChanged.emit()

    def _show_coverage(self, image_size: tuple[int, int]) -> None:
        self.coverage = (coverage_map([v.left_corners for v in self.views], image_size),
                         coverage_map([v.right_corners for v in self.views], image_size))
        self.left_view.show_coverage(self.coverage[0].counts)
        self.right_view.show_coverage(self.coverage[1].counts)
        if self.views:
            self.coverage_label.setText(f"coverage: left {self.coverage[0].fraction_covered:.0%}, "
                                        f"right {self.coverage[1].fraction_covered:.0%} of the image")
        else:
            self.coverage_label.setText("coverage: no views yet")

    def _show_progress(self, note: str = "") -> None:
        n, target = len(self.views), self._target_views()
        more = "" if n >= MIN_VIEWS else f" (at least {MIN_VIEWS} to calibrate)"
        self.count_label.setText(f"{n} of {target} views{more}{note}")

    def _set_capture_enabled(self, enabled: bool, reason: str) -> None:
        self.capture_button.setEnabled(enabled)
        self.capture_button.setToolTip(reason)
        self.capture_reason.setText(reason)
