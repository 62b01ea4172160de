"""The calibration wizard's live feed: frames read and the checkerboard searched for off the GUI thread.

Why: a corner search takes 10-60 ms per image, too long for the GUI thread (docs/design.md, Habits). The loop
runs as a generator in a :class:`~snreg_gui.common.workers.Worker`: it builds the source there (building
one may take time), reads a pair, searches each eye on a reduced image (halved until at most
``DETECT_MAX_WIDTH`` wide; :func:`~snreg.calibration.checkerboard.find_corners` refines the corners
to sub-pixel there) and yields a :class:`LiveView` at most ``MAX_RATE_HZ`` times a second. The
corners only steer the operator (overlay, coverage, stillness); the calibration searches the captured
full-size images again. The source is closed in the loop's own thread when it stops.

>>> feed = LiveBoardFeed(make_source, board)
>>> worker = Worker(feed.frames)
>>> worker.yielded.connect(page.show_live_view); worker.returned.connect(page.show_feed_end); worker.start()
>>> feed.stop(); worker.quit(); worker.wait()
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from snreg.calibration.checkerboard import Board, find_corners
from snreg.sources import FrameSource, SourceState

MAX_RATE_HZ = 30.0
DETECT_MAX_WIDTH = 640
_PAUSED_POLL_S = 0.05


@dataclass(frozen=True, eq=False)
class LiveView:
    """One searched stereo pair.

    ``left_rgb``/``right_rgb``: the frame for display, RGB at ``display_scale`` of the camera size;
    ``left_grey``/``right_grey``: the full-size grey images a capture keeps; ``left_corners``/``right_corners``:
    (cols * rows, 2) full-size pixel positions, or None where the board was not found (the right eye is
    not searched when the left lacks it); ``image_size`` (width, height) of the camera.
    """

    index: int
    left_rgb: np.ndarray
    right_rgb: np.ndarray
    left_grey: np.ndarray
    right_grey: np.ndarray
    left_corners: np.ndarray | None
    right_corners: np.ndarray | None
    display_scale: float
    image_size: tuple[int, int]

    @property
    def both_found(self) -> bool:
        return self.left_corners is not None and self.right_corners is not None


def detection_scale(width: int) -> float:
    """The power-of-two fraction that brings an image ``width`` px wide to at most ``DETECT_MAX_WIDTH``."""
    scale = 1.0
    while width * scale > DETECT_MAX_WIDTH:
        scale /= 2.0
    return scale


class LiveBoardFeed:
    """The frame loop's state shared with the GUI thread: the board to search, and pause/stop requests.

    ``board`` may be replaced between frames from any thread (the loop reads it once per frame).
    """

    def __init__(self, make_source: Callable[[], FrameSource], board: Board):
        self.board = board
        self._make_source = make_source
        self._stop = threading.Event()
        self._paused = threading.Event()

    def pause(self) -> None:
        """Stop reading and searching (e.g. while calibrating, to leave the CPU to it) until :meth:`resume`."""
        self._paused.set()

    def resume(self) -> None:
        self._paused.clear()

    def stop(self) -> None:
        """Make the loop end after the current frame (it then closes the source); thread-safe."""
        self._stop.set()

    def frames(self) -> Iterator[LiveView]:
        """Generator for a Worker: yields LiveViews; returns the source's problem when the source ends or fails."""
        source = self._make_source()
        try:
            while not self._stop.is_set():
                started = time.perf_counter()
                if self._paused.is_set():
                    self._stop.wait(_PAUSED_POLL_S)
                    continue
                frame = source.read()
                if frame is not None:
                    yield self._search(frame.index, frame.left, frame.right, self.board)
                elif source.state is not SourceState.OPEN:
                    return source.problem
                self._stop.wait(max(0.0, 1.0 / MAX_RATE_HZ - (time.perf_counter() - started)))
            return None
        finally:
            source.close()

    @staticmethod
    def _search(index: int, left_bgr: np.ndarray, right_bgr: np.ndarray, board: Board) -> LiveView:
        height, width = left_bgr.shape[:2]
        scale = detection_scale(width)
        greys, smalls, corners = [], [], []
        for bgr in (left_bgr, right_bgr):
            grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
            small_bgr = bgr if scale == 1.0 else cv2.resize(bgr, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
            greys.append(grey)
            smalls.append(cv2.cvtColor(small_bgr, cv2.COLOR_BGR2RGB))
            found = None
            if not corners or corners[0] is not None:
                found = find_corners(cv2.cvtColor(small_bgr, cv2.COLOR_BGR2GRAY), board)
            # pixel centres: full-size x = (small x + 0.5) / scale - 0.5
            corners.append(None if found is None else (found + 0.5) / scale - 0.5)
        return LiveView(index, smalls[0], smalls[1], greys[0], greys[1], corners[0], corners[1], scale, (width, height))
