"""The review's video: the recorded pair at the timeline's cursor, with the probe overlay as tracked then.

Why here: decoding a pair takes tens of ms, so frames are fetched in a worker, one at a time; while one is being
decoded only the newest request waits (scrubbing never builds a backlog). Without a recorded video the node
snapshots stay what the pair shows.

>>> scrubber = VideoScrubber()
>>> scrubber.frame_ready.connect(show)          # a snreg.session.review_video.ReviewFrame
>>> scrubber.load("s.h5", review.t0_ns); scrubber.show_at(12.5)
"""

from __future__ import annotations

from PySide6.QtCore import QObject, Signal

from snreg.session.review_video import ReviewVideo
from snreg_gui.common.workers import Worker


class VideoScrubber(QObject):
    """Fetches the pair at a time from a session's video in workers; ``frame_ready(ReviewFrame)`` when it is there,
    ``available(bool)`` once the video is open (False: the session has none)."""

    frame_ready = Signal(object)
    available = Signal(bool)

    def __init__(self):
        super().__init__()
        self.video: ReviewVideo | None = None
        self._worker: Worker | None = None
        self._wanted: float | None = None
        self._opening = False
        self._then: list = []                        # what waits for the video being opened (when_opened)

    def load(self, path: str, t0_ns: int) -> None:
        """Open the session's video (in a worker); a frame asked for meanwhile is shown once it is open."""
        self.close()
        self._opening = True
        self._run(Worker(ReviewVideo.open, path, t0_ns), self._opened)

    def show_at(self, t_s: float) -> None:
        """Show the pair at ``t_s`` (seconds from the review origin) as soon as the worker is free."""
        self._wanted = float(t_s)
        if self._worker is None:
            self._next()

    def when_opened(self, then) -> None:
        """Call ``then()`` once the video being opened is open (its file closed again); now when none is opening."""
        if not self._opening:
            return then()
        self._then.append(then)

    def _opened(self, video) -> None:
        self.video, self._opening = video, False
        self.available.emit(video is not None)
        self._call_waiting()

    def _call_waiting(self) -> None:
        waiting, self._then = self._then, []
        for then in waiting:
            then()

    def _next(self) -> None:
        if self._wanted is None or self.video is None or self._opening:
            return
        t_s, self._wanted = self._wanted, None
        self._run(Worker(self.video.frame_at, t_s), self._fetched)

    def _fetched(self, frame) -> None:
        if frame is not None:
            self.frame_ready.emit(frame)

    def _run(self, worker: Worker, returned) -> None:
        worker.returned.connect(returned)
        worker.errored.connect(lambda _: None)       # a damaged video shows nothing there; verify names it
        worker.finished.connect(lambda: self._finished(worker))
        self._worker = worker
        worker.start()

    def _finished(self, worker: Worker) -> None:
        if worker is not self._worker:               # one that :meth:`close` already waited for
            return
        worker.wait()
        opening, self._worker, self._opening = self._opening, None, False
        if opening:                                  # the open failed: nothing more will come of it
            self._call_waiting()
        self._next()

    def close(self) -> None:
        """Wait for the frame being fetched and close the video (safe to call twice)."""
        if self._worker is not None:
            self._worker.wait()
            self._worker = None
        if self.video is not None:
            self.video.close()
            self.video = None
        self._wanted, self._opening, self._then = None, False, []     # a load superseded announces nothing
