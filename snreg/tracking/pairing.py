"""Left/right frame pairing by host timestamp, for eyes captured by separate threads (thesis §3.4.2).

The thesis rule: keep the left/right time difference at most 15 ms; when it grows larger,
skip frames until it is under 10 ms again, or until it stops improving. Here: the oldest
waiting left and right frames form a pair when ``|t_right - t_left| <= max_skew_ms``.
Otherwise the eye that is behind (the older frame) skips its frame, and keeps skipping
while the difference is at least ``resync_skew_ms`` and the next frame of that eye would
make it smaller. A pair is only ever emitted within ``max_skew_ms``.

Decisions depend on the timestamps alone, not on the order in which the two threads
deliver: when the rule needs the behind eye's next frame, the pairer waits for it. The
statistics are those the thesis reports (mean -1 +- 4 ms there).
"""

from __future__ import annotations

import math
import threading
from collections import deque
from dataclasses import dataclass

import numpy as np

from snreg.sources.frames import StereoFrame, check_bgr

__all__ = ["StereoPairer", "SkewStats"]

_LEFT, _RIGHT = 0, 1
_EYES = ("left", "right")


@dataclass(frozen=True)
class SkewStats:
    """Right-minus-left time differences of the emitted pairs (ms), and frames skipped per eye."""

    pairs: int
    mean_ms: float          # NaN before the first pair
    std_ms: float           # population standard deviation; NaN before the first pair
    max_abs_ms: float       # largest |right - left|; NaN before the first pair
    skipped_left: int
    skipped_right: int

    @property
    def skipped(self) -> int:
        return self.skipped_left + self.skipped_right


class StereoPairer:
    """Pairs frames pushed per eye with non-decreasing host timestamps (ns); thread-safe.

    ``push_left``/``push_right`` return the pairs that the new frame completed (usually
    none or one) as :class:`StereoFrame`, indexed from 0. At most ``max_pending`` frames
    wait per eye (an eye whose partner stopped delivering); older ones count as skipped.
    """

    def __init__(self, *, max_skew_ms: float = 15.0, resync_skew_ms: float = 10.0, max_pending: int = 16):
        if not 0 < resync_skew_ms <= max_skew_ms:
            raise ValueError(f"Need 0 < resync_skew_ms <= max_skew_ms, got {resync_skew_ms} and {max_skew_ms} ms.")
        if max_pending < 2:
            raise ValueError(f"max_pending must be at least 2 frames, got {max_pending}.")
        self._max_ns, self._resync_ns = max_skew_ms * 1e6, resync_skew_ms * 1e6
        self._max_pending = int(max_pending)
        self._queues: tuple[deque, deque] = (deque(), deque())
        self._last_t: list[int | None] = [None, None]
        self._skipped = [0, 0]
        self._resyncing = False
        self._lock = threading.Lock()
        self._n, self._mean, self._m2, self._max_abs = 0, 0.0, 0.0, 0.0

    def push_left(self, t_ns: int, frame: np.ndarray) -> list[StereoFrame]:
        return self._push(_LEFT, t_ns, frame)

    def push_right(self, t_ns: int, frame: np.ndarray) -> list[StereoFrame]:
        return self._push(_RIGHT, t_ns, frame)

    @property
    def pending(self) -> tuple[int, int]:
        """Frames waiting for a partner: (left, right)."""
        with self._lock:
            return len(self._queues[_LEFT]), len(self._queues[_RIGHT])

    def stats(self) -> SkewStats:
        with self._lock:
            if self._n == 0:
                return SkewStats(0, math.nan, math.nan, math.nan, *self._skipped)
            return SkewStats(self._n, self._mean, math.sqrt(self._m2 / self._n), self._max_abs, *self._skipped)

    def _push(self, eye: int, t_ns: int, frame: np.ndarray) -> list[StereoFrame]:
        check_bgr(frame, f"{_EYES[eye]} frame")
        t_ns = int(t_ns)
        with self._lock:
            last = self._last_t[eye]
            if last is not None and t_ns < last:
                raise ValueError(f"The {_EYES[eye]} timestamps must not go backwards: {t_ns} ns came after {last} ns.")
            self._last_t[eye] = t_ns
            queue = self._queues[eye]
            queue.append((t_ns, frame))
            if len(queue) > self._max_pending:
                self._skip(eye)
            return self._drain()

    def _drain(self) -> list[StereoFrame]:
        left, right = self._queues
        pairs = []
        while left and right:
            d = right[0][0] - left[0][0]
            behind = _LEFT if d > 0 else _RIGHT
            if abs(d) > self._max_ns:
                self._resyncing = True
                self._skip(behind)
                continue
            if self._resyncing and abs(d) >= self._resync_ns:
                queue = self._queues[behind]
                if len(queue) < 2:
                    break                      # wait: does the behind eye's next frame do better?
                d_next = right[0][0] - queue[1][0] if behind == _LEFT else queue[1][0] - left[0][0]
                if abs(d_next) < abs(d):
                    self._skip(behind)
                    continue
            self._resyncing = False
            pairs.append(self._emit())
        return pairs

    def _skip(self, eye: int) -> None:
        self._queues[eye].popleft()
        self._skipped[eye] += 1

    def _emit(self) -> StereoFrame:
        (t_left, left), (t_right, right) = self._queues[_LEFT].popleft(), self._queues[_RIGHT].popleft()
        pair = StereoFrame(left, right, t_left, t_right, self._n)
        skew = pair.skew_ms
        self._n += 1
        delta = skew - self._mean
        self._mean += delta / self._n
        self._m2 += delta * (skew - self._mean)
        self._max_abs = max(self._max_abs, abs(skew))
        return pair
