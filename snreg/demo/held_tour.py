"""The demo tour's clock: which frame of the tour the live feed shows, each rest held until a node is stored on it.

Why (issue 35): the live feed skips frames when processing falls behind, so on a loaded computer a rest of fixed
wall-clock length ended before its store window filled and the demo failed. A technician holds the probe on the node
until it is stored, and so does the demo's: a rest lasts until :meth:`HeldTour.release` (the node stored: the probe
lifts ``lead_frames`` later) or, with nobody storing, after ``max_hold_frames`` frames delivered past the rest's
nominal end (counted in frames the feed delivered, so a loaded computer gets as many to fill its window); it also ends
early when the node is stored early, so an unloaded computer runs the tour faster. Feed frame ``k`` (counted from the
feed's epoch) maps to the tour's frame through a :class:`~snreg.demo.motion_timeline.MotionTimeline` in seconds, the
one the surgery demo's IMU simulator plays (each new run is handed to ``send``), so the camera and the IMU hold and
go on together.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence

from snreg.demo.motion_timeline import MotionTimeline, Run

__all__ = ["HeldTour"]


class HeldTour:
    """Tour frames of a feed at ``fps`` over a tour of ``cycle`` frames (repeating) whose rests are ``rest_spans``
    ((first frame, frames) per rest, in tour order). ``held``: rests wait for :meth:`release` (else the tour runs
    with the clock, rests of fixed length, and releases do nothing). ``send``: called with each run of the timeline
    (the first at once), in seconds."""

    def __init__(self, rest_spans: Sequence[tuple[int, int]], cycle: int, fps: float, *, held: bool = True,
                 lead_frames: int = 0, max_hold_frames: int = 1800, send: Callable[[Run], None] | None = None):
        self.rest_spans, self.cycle, self.fps = [(int(a), int(n)) for a, n in rest_spans], int(cycle), float(fps)
        self.held, self.lead_frames, self.max_hold_frames = bool(held), int(lead_frames), int(max_hold_frames)
        self._send = send
        self._holds = sorted(first + frames - 1 for first, frames in self.rest_spans)   # each rest's last frame
        self._lock = threading.Lock()
        self._held_frames = 0                           # frames delivered while held at the current rest's end
        first = Run(0.0, 0.0, self._hold_after(-1) / self.fps if self.held else math.inf)
        self.timeline = MotionTimeline(first)
        if send is not None:
            send(first)

    def tour_frame(self, feed_index: int) -> int:
        """The tour frame at feed frame ``feed_index``."""
        return round(float(self.timeline.motion_s(feed_index / self.fps)[0]) * self.fps)

    def shown_frame(self, feed_index: int) -> int:
        """The tour frame to render for feed frame ``feed_index``, which the feed delivers (call it once per frame
        delivered: a live feed renders only those). It is the tour's frame, or while resting the rest frame the feed
        index picks (the same pose: a held rest still shows fresh sensor noise from frame to frame). A rest held past
        its end for ``max_hold_frames`` delivered frames (frames processed, not wall-clock time: a loaded computer
        gets as many) is released here."""
        frame = self.tour_frame(feed_index)
        if self.held:
            with self._lock:
                if round(self.timeline.last.until_s * self.fps) == frame:
                    self._held_frames += 1
                    if self._held_frames >= self.max_hold_frames:
                        self._release(feed_index, feed_index)
        rest = self._rest_at(frame)
        if rest is None or not self.held:               # timed rests: every frame its own, as the feed counts them
            return frame
        first, frames = rest
        return frame - frame % self.cycle + first + feed_index % frames

    def resting(self, tour_frame: int) -> bool:
        """Whether ``tour_frame`` lies in a rest."""
        return self._rest_at(tour_frame) is not None

    def release(self, feed_index: int, now_index: int | None = None) -> bool:
        """The node was stored on feed frame ``feed_index``: the rest that frame shows ends ``lead_frames`` after
        ``now_index`` (the feed's clock now; default ``feed_index``). False (nothing changes) when not held, when that
        frame is not resting, or when that rest's end is set already (a store seen late never ends the next rest)."""
        if not self.held:
            return False
        with self._lock:
            return self._release(feed_index, max(feed_index, feed_index if now_index is None else now_index))

    def _release(self, feed_index: int, now_index: int) -> bool:
        last = self.timeline.last
        frame = round(float(self.timeline.motion_s(feed_index / self.fps)[0]) * self.fps)
        if not self.resting(frame) or self._hold_after(frame - 1) != round(last.until_s * self.fps):
            return False                                                # moving, or this rest's end is set
        if round(last.start_s * self.fps) > now_index:
            return False
        hold = round(last.until_s * self.fps)
        run = Run((now_index + self.lead_frames) / self.fps, hold / self.fps, self._hold_after(hold) / self.fps)
        self.timeline.add(run)
        self._held_frames = 0
        if self._send is not None:
            self._send(run)
        return True

    def _hold_after(self, frame: int) -> int:
        """The first rest end after tour frame ``frame`` (rests repeat with the tour)."""
        base = max(frame, 0) // self.cycle * self.cycle
        for cycle_start in (base, base + self.cycle):
            for hold in self._holds:
                if cycle_start + hold > frame:
                    return cycle_start + hold
        raise ValueError("a tour needs at least one rest")

    def _rest_at(self, tour_frame: int) -> tuple[int, int] | None:
        within = tour_frame % self.cycle
        for first, frames in self.rest_spans:
            if first <= within < first + frames:
                return first, frames
        return None
