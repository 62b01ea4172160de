"""Motion time against clock time: a scripted motion that runs at the clock's pace up to a hold point and waits there
until it is told to go on.

Why: the demo's technician holds the probe on a node until it is stored, however long a loaded computer takes to
fill the store window (issue 35); with the surgery camera the camera holds too, and the simulated IMU, a process of
its own playing the camera's motion in real time, must hold with it. Both sides map the clock to the motion with one
:class:`MotionTimeline`: the demo rig decides each run (:class:`~snreg.demo.held_tour.HeldTour`) and sends it to the
simulator as one text line on the simulator's standard input (``snreg imu simulate --timeline-stdin``), a channel of
the demo's own beside the pseudo-terminal: the device's serial protocol (docs/design.md, Contracts) is unchanged.

Times are seconds from the motion's start (``epoch``) on the clock both processes share. A run says: from clock time
``start_s`` the motion time is ``from_s`` and advances with the clock until ``until_s``, where it stops. Before the
first run starts the motion time is the clock time (the profile holds its first pose before 0). A run starting
before the motion reaches its ``from_s`` skips ahead; a demo only does so, and only holds, where the motion is
still (a rest), so the orientation stays continuous and the angular rate zero there.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import IO

import numpy as np

__all__ = ["Run", "MotionTimeline"]


@dataclass(frozen=True)
class Run:
    """From clock time ``start_s`` the motion runs from ``from_s`` at the clock's pace until ``until_s`` (s)."""

    start_s: float
    from_s: float
    until_s: float = math.inf

    def line(self) -> str:
        """The run as the one text line the simulator reads: ``START FROM UNTIL`` (seconds; ``inf``: never stops)."""
        return f"{self.start_s!r} {self.from_s!r} {self.until_s!r}\n"

    @classmethod
    def parse(cls, line: str) -> "Run":
        """Inverse of :meth:`line`; ValueError in one sentence when the line is not three numbers."""
        try:
            start, begin, until = (float(v) for v in line.split())
        except ValueError:
            raise ValueError(f"a motion run is three numbers, START FROM UNTIL in seconds, not {line.strip()!r}") from None
        if not (math.isfinite(start) and math.isfinite(begin) and until >= begin):
            raise ValueError(f"a motion run needs a finite start and motion time and UNTIL >= FROM, not {line.strip()!r}")
        return cls(start, begin, until)


class MotionTimeline:
    """Motion time (s) at clock time (s) from a list of :class:`Run` in clock order; thread-safe (a reader thread adds
    runs while another maps times)."""

    def __init__(self, first: Run | None = None):
        self._runs: list[Run] = [first if first is not None else Run(0.0, 0.0)]
        self._lock = threading.Lock()

    @property
    def last(self) -> Run:
        """The run added last (the one in force once its start has come)."""
        with self._lock:
            return self._runs[-1]

    def add(self, run: Run) -> None:
        """Append ``run``; it starts no earlier than the run before it."""
        with self._lock:
            if run.start_s < self._runs[-1].start_s:
                raise ValueError(f"a motion run cannot start ({run.start_s:.3f} s) before the one before it "
                                 f"({self._runs[-1].start_s:.3f} s)")
            self._runs.append(run)

    def motion_s(self, t_s) -> np.ndarray:
        """Motion time(s) at clock time(s) ``t_s`` (array like ``t_s``, at least 1-D)."""
        return self._evaluate(t_s)[0]

    def rate(self, t_s) -> np.ndarray:
        """1 where the motion runs at clock time(s) ``t_s``, 0 where it holds (scales the angular velocity)."""
        return np.where(self._evaluate(t_s)[1], 0.0, 1.0)

    def _evaluate(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Motion times and whether each is held, at clock times ``t_s``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        with self._lock:
            runs = list(self._runs)
        starts = np.array([run.start_s for run in runs])
        froms = np.array([run.from_s for run in runs])
        untils = np.array([run.until_s for run in runs])
        k = np.searchsorted(starts, t, side="right") - 1
        before = k < 0                                  # before the first run: the clock itself
        k = np.maximum(k, 0)
        running = froms[k] + (t - starts[k])
        held = ~before & (running >= untils[k])
        return np.where(before, t, np.minimum(running, untils[k])), held

    def follow(self, stream: IO[str]) -> None:
        """Add the runs read from ``stream``, one per line, until it ends (run it in a thread of its own). A line that
        is not a run ends the reading: its sender is broken and the motion holds where it stopped."""
        for line in stream:
            if not line.strip():
                continue
            try:
                self.add(Run.parse(line))
            except ValueError:
                return
