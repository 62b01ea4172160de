"""Where the live loop's pairs are tracked: at once in the caller's thread (:class:`InlineTracking`), or in a process of
its own (:class:`TrackingProcess`, issue 36), both through :func:`~snreg.workflow.pair_tracking.track_pair`.

Why a process: the probe tracker and the insertion tracker are numpy-heavy Python between OpenCV calls, and in the
app's process they held the GIL the GUI thread waits for (its stalls were mostly such waits: with the tracking
replaced by a sleep the p99 stall fell from 38 to 18 ms). In a process of their own they also run beside the
acquisition's other work: while pair k is tracked there, the worker reads and records pair k+1 (pipelining; the
outcomes still come back in frame order). The child runs :data:`~snreg.workflow.tracking_child.NICER` steps nicer
than the app: at its own priority it took the CPU the GUI thread needed once the two cores were full (longest stall
66-78 ms against 46-49 in one process), niced the GUI thread gets a core first (52 ms, p99 28) and tracking the rest.

How, after :class:`~snreg.session.video.StereoRecorder`: the child is started with ``python -m
snreg.workflow.tracking_child`` (no fork of a process that runs Qt); the pairs travel through slots of shared memory
this process owns and unlinks (its resource tracker unlinks it as well when this process is killed), small pickled
messages over the child's stdin and stdout. The child ends at the end of its stdin, so it never outlives the app. The
insertion tracker (its keyframes) lives in the child while it runs and comes back at :meth:`TrackingProcess.close`,
so a later acquisition goes on with it. A child that dies or does not answer within :data:`ANSWER_S` raises
:class:`TrackingStopped`, saying how it ended ("killed by signal 9"); the acquisition then starts a new one
(:mod:`snreg.workflow.supervised_tracking`).
"""

from __future__ import annotations

import collections
import pickle
import queue
import subprocess
import sys
import threading
from multiprocessing import shared_memory

import numpy as np

from snreg.camera import StereoCalibration
from snreg.child_process import end_child
from snreg.odometry import InsertionTracker
from snreg.probe import ProbeModel
from snreg.tracking import StereoTracker
from snreg.workflow.pair_tracking import TrackedPair, track_pair

__all__ = ["InlineTracking", "TrackingProcess", "TrackingStopped", "ANSWER_S", "START_S"]

SLOTS = 3           # pairs in shared memory: one tracked, one or two waiting (a pair finding none goes in its message)
START_S = 60.0      # for the child's first answer: its imports and trackers (a second or two on a quiet machine)
ANSWER_S = 10.0     # for each answer after that (a full-HD pair takes well under 0.1 s)
STOP_S = 10.0       # for the child to hand back the insertion tracker and end, before it is killed


class TrackingStopped(RuntimeError):
    """The tracking process died or stopped answering; the message says which, in words."""


class InlineTracking:
    """Each pair tracked at once in the caller's thread (``snreg demo --headless``, retracking, tests)."""

    pid = None

    def __init__(self, tracker: StereoTracker, insertion: InsertionTracker | None):
        self.tracker, self.insertion = tracker, insertion
        self._done: collections.deque[TrackedPair] = collections.deque()

    def submit(self, left: np.ndarray, right: np.ndarray, earth_from_imu: np.ndarray) -> None:
        self._done.append(track_pair(self.tracker, self.insertion, left, right, earth_from_imu))

    def ready(self) -> bool:
        """The oldest pair submitted has its result (always, here)."""
        return bool(self._done)

    def result(self) -> TrackedPair:
        return self._done.popleft()

    def close(self) -> InsertionTracker | None:
        return self.insertion


class TrackingProcess:
    """Pairs tracked in a child process, in the order submitted; :meth:`submit` returns at once, :meth:`result`
    waits for the oldest pair's (module docstring). ``insertion`` goes to the child and comes back at
    :meth:`close`."""

    def __init__(self, calibration: StereoCalibration, probe: ProbeModel, insertion: InsertionTracker | None, *,
                 answer_s: float = ANSWER_S, start_s: float = START_S):
        width, height = calibration.image_size
        self._shape = (2, int(height), int(width), 3)
        self._pair_bytes = int(np.prod(self._shape))
        self._answer_s, self._start_s = answer_s, start_s
        self._insertion = insertion
        self._memory = shared_memory.SharedMemory(create=True, size=SLOTS * self._pair_bytes)
        self._free = list(range(SLOTS))
        self._in_flight: collections.deque[int] = collections.deque()       # the slot of each pair submitted
        self._answers: queue.Queue = queue.Queue()
        self._started = False
        self._problem = ""
        self._errors: collections.deque[str] = collections.deque(maxlen=5)  # the child's last lines on stderr
        self._process = subprocess.Popen([sys.executable, "-m", "snreg.workflow.tracking_child", self._memory.name],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        threading.Thread(target=self._listen, name="snreg-tracking-answers", daemon=True).start()
        threading.Thread(target=self._listen_errors, name="snreg-tracking-errors", daemon=True).start()
        self._send((calibration, probe, insertion, self._shape))

    @property
    def pid(self) -> int:
        """The child's process id (the bench reads its CPU time)."""
        return self._process.pid

    def submit(self, left: np.ndarray, right: np.ndarray, earth_from_imu: np.ndarray) -> None:
        """Send a pair (BGR) to be tracked at ``earth_from_imu``; :class:`TrackingStopped` when the child is gone."""
        slot = self._free.pop() if self._free and left.shape == right.shape == self._shape[1:] else -1
        if slot >= 0:
            view = np.ndarray(self._shape, np.uint8, self._memory.buf, slot * self._pair_bytes)
            view[0], view[1] = left, right
            del view
            message = ("pair", slot, None, None, np.asarray(earth_from_imu, dtype=float))
        else:                                  # another size, or every slot taken: the images travel in the message
            message = ("pair", -1, left, right, np.asarray(earth_from_imu, dtype=float))
        self._in_flight.append(slot)
        self._send(message)

    def ready(self) -> bool:
        """The oldest pair submitted has its answer (or the child is gone: :meth:`result` then says why)."""
        return not self._answers.empty()

    def result(self) -> TrackedPair:
        """The oldest pair's, waiting for it; the child's error for that pair is raised here (as tracking in this
        thread raises it); :class:`TrackingStopped` when the child died or did not answer in time."""
        if self._problem:
            raise TrackingStopped(self._problem)
        try:
            answer = self._answers.get(timeout=self._answer_s if self._started else self._start_s)
        except queue.Empty:
            self._stop_with(f"the tracking process did not answer within "
                            f"{self._answer_s if self._started else self._start_s:.0f} s")
        if answer[0] == "ended":
            self._stop_with("the tracking process ended", ended=True)
        slot = self._in_flight.popleft()
        if slot >= 0:
            self._free.append(slot)
        if answer[0] == "error":
            raise answer[1]
        return answer[1]

    def close(self) -> InsertionTracker | None:
        """End the child (pairs still in flight are dropped: read their results first) and free the shared memory;
        the insertion tracker as the child left it (as it was sent when the child cannot hand it back)."""
        try:
            if not self._problem and self._process.poll() is None:
                self._send(("stop",))
                while True:                 # answers of pairs still in flight, then the tracker
                    answer = self._answers.get(timeout=STOP_S)
                    if answer[0] == "kept":
                        self._insertion = answer[1]
                        break
                    if answer[0] == "ended":
                        break
        except (TrackingStopped, queue.Empty):
            pass
        finally:
            self._end_process()
        return self._insertion

    def _send(self, message) -> None:
        try:
            self._process.stdin.write(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))
            self._process.stdin.flush()
        except (BrokenPipeError, OSError, ValueError):
            self._stop_with("the tracking process ended", ended=True)

    def _stop_with(self, problem: str, ended: bool = False):
        """End the child and raise :class:`TrackingStopped` with ``problem``; ``ended``: it ended by itself, and how
        (its signal or exit status, its last words on stderr) is added in brackets."""
        self._end_process()
        self._problem = problem + (self._how_ended() if ended else "")
        raise TrackingStopped(self._problem)

    @property
    def answering(self) -> bool:
        """The child has started (its trackers built) and answers pairs."""
        return self._started and not self._problem

    @property
    def ended(self) -> bool:
        """The child is gone (died, or ended by :meth:`close`)."""
        return bool(self._problem) or self._process.poll() is not None

    def _end_process(self) -> None:
        """Close the child's stdin (it ends), wait a little, kill it if it does not; free the shared memory (once)."""
        end_child(self._process, STOP_S)
        if self._memory is not None:
            self._memory.close()
            self._memory.unlink()
            self._memory = None

    def _listen(self) -> None:
        """The child's answers, one pickle each, onto the queue; "ended" when its stdout closes."""
        try:
            while True:
                answer = pickle.load(self._process.stdout)
                if answer[0] == "ready":
                    self._started = True
                else:
                    self._answers.put(answer)
        except (EOFError, OSError, pickle.UnpicklingError, ValueError):
            pass
        self._answers.put(("ended",))

    def _listen_errors(self) -> None:
        for raw in self._process.stderr:
            self._errors.append(raw.decode("utf-8", "replace").strip())

    def _how_ended(self) -> str:
        """How the child ended, in brackets: killed by which signal or its exit status, and its last words on stderr
        ("killed by signal 9", "exit status 1: MemoryError"); call once it was waited for."""
        code = self._process.returncode
        how = (f"killed by signal {-code}" if code is not None and code < 0 else
               f"exit status {code}" if code is not None else "")
        lines = [line for line in self._errors if line]
        said = ": ".join(part for part in (how, lines[-1] if lines else "") if part)
        return f" ({said})" if said else ""
