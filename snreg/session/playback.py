"""A recorded session's video as a frame source: the pairs of ``streams/frames`` at their recorded pace.

Why: a replay must run the code a live session runs (docs/design.md, Habits), so the recorded feeds come back through the
:class:`~snreg.sources.FrameSource` interface. Live (the default), it behaves as a camera does (docs/design.md, Conventions): row k
is due ``(t_k - t_0) / speed`` after ``start_ns``, :meth:`read` waits for the next due frame and, when the consumer has
fallen behind, skips to the newest one, and each frame is stamped on the host clock when it is taken. With
``live=False`` every recorded frame is delivered, none before it is due, each stamped with the host time it was due
at: a slow consumer falls behind but meets every frame with the IMU replay's orientation of its moment (a
reproduction, frame for frame).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from snreg.errors import SourceError
from snreg.session.reader import readable_rows
from snreg.session.session import Session
from snreg.session.video import RecordedPairs, VideoSegment, rows_with_video
from snreg.sources import FrameSource, SourceState, StereoFrame


def recorded_origin_ns(path: str | Path) -> int:
    """The host time (ns) a replay of ``path`` counts from: the first frame row or IMU sample, whichever is first."""
    with Session.open(path) as session:
        firsts = [int(np.min(rows["t_host_ns"])) for rows in (_rows(session, "frames"), _rows(session, "imu"))
                  if len(rows)]
    return min(firsts) if firsts else 0


def _rows(session: Session, name: str) -> np.ndarray:
    stream = session.stream(name)
    return readable_rows(stream) if hasattr(stream, "id") else np.asarray(stream)


class RecordedFeed(FrameSource):
    """The recorded pairs of a session (:meth:`Session.videos`), paced by their rows' times ``speed`` times faster.

    ``origin_ns``: the recorded time played at ``start_ns`` (default: the first row; a replay that plays the IMU
    too passes :func:`recorded_origin_ns`); ``start_ns``: the host time the replay starts (default: the first read).
    """

    def __init__(self, path: str | Path, *, speed: float = 1.0, live: bool = True, origin_ns: int | None = None,
                 start_ns: int | None = None, clock: Callable[[], int] = time.perf_counter_ns):
        path = Path(path)
        super().__init__(f"Replay of {path.name}")
        if not speed > 0:
            raise SourceError(f"The replay speed must be a positive number, not {speed!r}.")
        try:
            with Session.open(path) as session:
                self._segments: list[VideoSegment] = session.videos()
                rows = _rows(session, "frames")
        except (OSError, ValueError) as err:
            raise SourceError(f"{path}: cannot be replayed ({err}).") from None
        if not self._segments:
            raise SourceError(f"{path} has no recorded video to replay; choose a session recorded with video.")
        self.path, self.speed, self._live, self._clock = path, float(speed), bool(live), clock
        self._rows = np.flatnonzero(rows_with_video(path, self._segments, len(rows)))   # the rows it can play
        self._times = np.asarray(rows["t_host_ns"], dtype=np.int64)[self._rows]
        self._right_times = np.asarray(rows["t_device_ns"], dtype=np.int64)[self._rows]   # the right eye's
        if not len(self._rows):
            raise SourceError(f"{path}: its video holds no frame of its frame rows; nothing to replay.")
        self._origin = int(self._times[0]) if origin_ns is None else int(origin_ns)
        self._start = start_ns
        self._next = 0
        self._pairs = RecordedPairs(path, self._segments)

    @property
    def frame_size(self) -> tuple[int, int]:
        """(width, height) of each eye."""
        return self._segments[0].width, self._segments[0].height

    def __len__(self) -> int:
        """The frames it plays (the rows with a pair in the video)."""
        return len(self._times)

    def _read(self) -> StereoFrame | None:
        k = self._due()
        if k >= len(self._times):
            self._stop(SourceState.ENDED, f"{self.name} played all {len(self._times)} recorded frames.")
            return None
        self._next, row = k + 1, int(self._rows[k])
        pair = self._pair(row)
        if pair is None and self.state is SourceState.OPEN:
            self._stop(SourceState.ENDED, f"{self.name} ended at frame {row}: the video holds no more frames.")
        if pair is None:
            return None
        if self._live:
            t_left = t_right = self._clock()
        else:
            t_left, t_right = self._due_ns(self._times[k]), self._due_ns(self._right_times[k])
        return self._frame(pair[0], pair[1], t_left, t_right, row)

    def _due_ns(self, recorded_ns) -> int:
        """The host time a recorded time is played at."""
        return int(self._start + (int(recorded_ns) - self._origin) / self.speed)

    def _due(self) -> int:
        """The position (in the rows it plays) to take now: live, the newest due (after waiting for the next if none
        is); else the next one, once it is due."""
        now = self._clock()
        if self._start is None:
            self._start = now
        played = self._origin + (now - self._start) * self.speed           # the recorded time being played now
        due = int(np.searchsorted(self._times, played, side="right")) - 1 if self._live else -1
        if due < self._next and self._next < len(self._times):
            time.sleep(max(self._due_ns(self._times[self._next]) - now, 0) / 1e9)
            due = self._next
        return max(due, self._next)

    def _pair(self, row: int) -> tuple[np.ndarray, np.ndarray] | None:
        try:
            return self._pairs.pair(row)
        except OSError as err:
            self._stop(SourceState.LOST, f"{err}; check that the videos are beside the session file.")
            return None

    def _release(self) -> None:
        self._pairs.close()
