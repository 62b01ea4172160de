"""The live loop's tracking process, kept alive: a child that dies mid-acquisition (killed, out of memory, crashed) is
replaced by a new one, so the probe's tracking comes back by itself while the feed, the IMU and the stored nodes go on.

What a technician sees: the pairs in flight when the child died, and those read while its successor starts (its
imports and trackers: a second or two), are tracked in the acquisition's own thread, so no pair is lost and the feed
never waits for the new child; once the new child answers, pairs go to it again. The camera's insertion is no longer
tracked after a death: the insertion tracker's keyframes went with the child, and one started afresh would take the
camera to be at its start, wherever it slid since (its pairs are lost, in words, and the store guard treats them so).
A child that dies :data:`RESTARTS` times in a row (none of its successors tracked a pair, or each died before it
started) is not started again: every pair is then tracked in the acquisition's thread (slower), as when the first child
cannot start. Each death is said in one line (:attr:`SupervisedTracking.problem`, "the tracking process ended (killed
by signal 9); restarted") and counted (:attr:`SupervisedTracking.stops`), for the status line and the session's events.
"""

from __future__ import annotations

import collections
import time

import numpy as np

from snreg.camera import StereoCalibration
from snreg.odometry import InsertionTracker
from snreg.probe import ProbeModel
from snreg.tracking import StereoTracker
from snreg.workflow.pair_tracking import TrackedPair
from snreg.workflow.tracking_process import START_S, InlineTracking, TrackingProcess, TrackingStopped

__all__ = ["SupervisedTracking", "RESTARTS"]

RESTARTS = 3        # new children started in a row (none of them tracked a pair) before tracking stays in this thread

_HERE, _CHILD = "here", "child"


class SupervisedTracking:
    """Pairs tracked in a :class:`~snreg.workflow.tracking_process.TrackingProcess` (with ``insertion``), in the order
    submitted, restarted when it dies (module docstring); the interface of
    :class:`~snreg.workflow.tracking_process.InlineTracking`. ``tracker``: the probe tracker pairs are tracked with in
    this thread meanwhile; ``start_s``: how long a new child may take to answer before it counts as dead."""

    def __init__(self, tracker: StereoTracker, calibration: StereoCalibration, probe: ProbeModel,
                 insertion: InsertionTracker | None, *, restarts: int = RESTARTS, start_s: float = START_S):
        self._setup = (calibration, probe)
        self._restarts, self._start_s = int(restarts), float(start_s)
        self._here = InlineTracking(tracker, None)
        self._child: TrackingProcess | None = TrackingProcess(calibration, probe, insertion)
        self._first = self._child                   # the child with the insertion tracker (close hands it back)
        self._born = time.monotonic()
        # per pair in flight: [where, left, right, earth_from_imu, its error when tracked here after its child died]
        self._flight: collections.deque[list] = collections.deque()
        self._in_a_row = 0                          # deaths since a child last tracked a pair
        self.insertion_tracked = insertion is not None
        self.problem = ""                           # the last death and what followed, in words ("" while none)
        self.stops = 0                              # deaths so far

    @property
    def pid(self) -> int | None:
        """The tracking child's process id (None once pairs are tracked in this thread for good)."""
        return None if self._child is None else self._child.pid

    @property
    def answering(self) -> bool:
        """Pairs go to a tracking child now (False while a restarted one starts, and once tracking stays here)."""
        return self._child is not None and self._child.answering

    def submit(self, left: np.ndarray, right: np.ndarray, earth_from_imu: np.ndarray) -> None:
        """Send a pair to the child, or track it here while a new child starts (or after the last has died)."""
        if self._child is not None and not self._child.answering and self._child is not self._first:
            self._check_starting()
        where = _CHILD if self._child is not None and (self._child is self._first or self._child.answering) else _HERE
        if where == _HERE:
            self._here.submit(left, right, earth_from_imu)      # its error (a pair of another size) raised now
        self._flight.append([where, left, right, earth_from_imu, None])
        if where == _HERE:
            return
        try:
            self._child.submit(left, right, earth_from_imu)
        except TrackingStopped as err:
            self._died(str(err))

    def ready(self) -> bool:
        """The oldest pair submitted has its result (or its child is gone: :meth:`result` then tracks it here)."""
        return bool(self._flight) and (self._flight[0][0] == _HERE or self._child.ready())

    def result(self) -> TrackedPair:
        """The oldest pair's; a child's error for that pair is raised here, as tracking here raises it."""
        where = self._flight[0][0]
        if where == _CHILD:
            try:
                tracked = self._child.result()
            except TrackingStopped as err:
                self._died(str(err))          # this pair and those after it: tracked here now
                return self.result()
            except BaseException:
                self._flight.popleft()
                raise
            self._flight.popleft()
            self._in_a_row = 0                # a child tracked a pair: the next death starts the count again
            return tracked
        error = self._flight.popleft()[4]
        if error is not None:                     # the pair a dead child had, of another size: its error, here
            raise error
        return self._here.result()

    def close(self) -> InsertionTracker | None:
        """End the child; the insertion tracker as the first child left it (None after a death: it died with it)."""
        kept = self._child.close() if self._child is not None else None
        self._child = None
        return kept if self.stops == 0 else None

    def _check_starting(self) -> None:
        """A new child that died or has not answered within ``start_s`` counts as a death."""
        if self._child.ended:
            try:
                self._child.result()         # raises how it ended
            except TrackingStopped as err:
                self._died(str(err))
        elif time.monotonic() - self._born > self._start_s:
            self._child.close()
            self._died(f"the tracking process did not start within {self._start_s:.0f} s")

    def _died(self, problem: str) -> None:
        """The child is gone: the pairs it had are tracked here (in order, after those tracked here already), and a
        new child is started unless :data:`RESTARTS` died in a row."""
        self.stops += 1
        self._in_a_row += 1
        for entry in self._flight:
            if entry[0] == _CHILD:
                entry[0] = _HERE
                try:
                    self._here.submit(*entry[1:4])
                except Exception as err:          # raised where that pair is finished, as the child would
                    entry[4] = err
        lost = "; the camera's insertion is no longer tracked" if self.insertion_tracked else ""
        self._child = None
        if self._in_a_row <= self._restarts:
            try:
                self._child, self._born = TrackingProcess(*self._setup, None), time.monotonic()
            except OSError as err:                  # no process can be started now (out of memory, of processes)
                problem = f"{problem}; a new one could not be started ({err})"
            else:
                again = f" ({self._in_a_row} times in a row)" if self._in_a_row > 1 else ""
                self.problem = f"{problem}; restarted{again}{lost}"
                return
        times = f", {self._in_a_row} times in a row" if self._in_a_row > 1 else ""
        self.problem = f"{problem}{times}; the probe is tracked in the acquisition's thread from now on (slower){lost}"
