"""Where the GUI thread is while it stalls: the bench's ``--stalls`` sampler, and what it did in each stall (ran,
waited for a CPU, slept: :func:`stall_split`, from :func:`sched_times` read at each heartbeat tick).

Why: a stall's length says nothing of its cause. A watchdog thread samples the GUI thread's Python stack whenever the
heartbeat has not ticked for ``late_ms``; the stacks seen most often are where to look. A stack that is only the event
loop (``app.exec``) means the thread was in Qt's own code (painting, layout) or waiting for the interpreter lock
another thread held; on Linux the two are told apart by the thread's state then (``/proc``): running (Qt's work, or
a turn of a busy machine's CPU it waits for) or asleep (for the interpreter lock another thread holds, so the stall is
that thread's work, or for another lock; issue 36). A stack with the app's frames says no more: the thread, running
Python, lets the lock go for the watchdog, so it is asleep whenever it is looked at. The watchdog itself needs that
lock to sample, so a stall under a long call that holds the lock is seen once it is released; the samples are where
the thread was, not a profile.
"""

from __future__ import annotations

import sys
import sysconfig
import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np

SAMPLE_S = 0.01
_STDLIB = sysconfig.get_paths()["stdlib"]
FRAMES_KEPT = 4             # the innermost frames of the app's code and pyqtgraph's, per sample


class StallSampler:
    """Samples the stack of the thread that creates it (the GUI thread) while ``last_tick()`` (perf_counter seconds)
    is over ``late_ms`` old; :meth:`stop`, then :meth:`top`."""

    def __init__(self, last_tick: Callable[[], float | None], late_ms: float = 50.0):
        self._target = threading.get_ident()
        self._stat = Path(f"/proc/self/task/{threading.get_native_id()}/stat")
        self._last_tick, self._late_s = last_tick, late_ms / 1e3
        self.samples: Counter[str] = Counter()
        self._lock = threading.Lock()       # top() may be read while the watchdog samples
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, name="bench-stall-sampler", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()

    def top(self, n: int = 8) -> list[tuple[str, int]]:
        """The ``n`` stacks sampled most often, with their sample counts (each sample is ``SAMPLE_S`` of stall)."""
        with self._lock:
            return self.samples.most_common(n)

    def _watch(self) -> None:
        while not self._stop.wait(SAMPLE_S):
            tick = self._last_tick()
            if tick is None or time.perf_counter() - tick < self._late_s:
                continue
            frame = sys._current_frames().get(self._target)      # noqa: SLF001 - the interpreter's one way to it
            if frame is not None:
                stack = _summary(frame) or _event_loop(thread_state(self._stat))
                with self._lock:
                    self.samples[stack] += 1


def thread_state(stat: Path) -> str:
    """"running" (or runnable: waiting for a CPU), "asleep" (for a lock, the interpreter's among them, or for input) or
    "" (unknown: no ``/proc``, or the thread ended), from a thread's ``/proc/.../stat``."""
    try:
        text = stat.read_text()
    except OSError:
        return ""
    code = text[text.rindex(")") + 2:][:1]             # the field after the name, which may hold spaces
    return {"R": "running", "S": "asleep", "D": "asleep"}.get(code, "")


def sched_times(schedstat: Path) -> tuple[float, float] | None:
    """(seconds running, seconds runnable but waiting for a CPU) a thread spent so far, from its
    ``/proc/.../schedstat``; None where it cannot be read (not Linux, no scheduler statistics, the thread ended)."""
    try:
        running_ns, waiting_ns = schedstat.read_text().split()[:2]
    except (OSError, ValueError):
        return None
    return int(running_ns) / 1e9, int(waiting_ns) / 1e9


def stall_split(ticks: list[float], sched: list[tuple[float, float]], over_ms: float) -> dict | None:
    """What the thread did in the gaps between consecutive ``ticks`` (perf_counter seconds) longer than ``over_ms``,
    from :func:`sched_times` read at each tick (``sched``, one per tick): ``{"stalls", "ms", "running_ms",
    "waiting_for_cpu_ms", "asleep_ms", "longest": {"ms", "running_ms", "waiting_for_cpu_ms", "asleep_ms"}}``, ms
    summed over those gaps (asleep: the rest of each gap, a lock waited for, the interpreter's among them); None
    without a reading per tick or a stall.

    Why: a stall on a loaded machine may be the thread waiting for a CPU, which no change of the app's removes; one
    spent asleep is another thread's (issue 36)."""
    if len(sched) != len(ticks) or len(ticks) < 2:
        return None
    gaps = np.diff(ticks) * 1e3
    used = np.diff(np.asarray(sched, dtype=float), axis=0) * 1e3      # (gaps, 2): running, waiting for a CPU
    stalled = np.flatnonzero(gaps > over_ms)
    if not len(stalled):
        return None
    running = np.minimum(used[stalled, 0], gaps[stalled])
    waiting = np.minimum(used[stalled, 1], gaps[stalled] - running)
    asleep = gaps[stalled] - running - waiting
    longest = int(np.argmax(gaps[stalled]))

    def split(index) -> dict:
        parts = (("ms", gaps[stalled]), ("running_ms", running), ("waiting_for_cpu_ms", waiting),
                 ("asleep_ms", asleep))
        return {name: round(float(np.sum(values[index])), 1) for name, values in parts}
    return {"stalls": len(stalled), **split(slice(None)), "longest": split(longest)}


def _event_loop(state: str) -> str:
    """A sample without the app's frames, in words, by the thread's ``state`` (:func:`thread_state`)."""
    return {"running": "event loop, running: Qt's own work (or waiting for a CPU)",
            "asleep": "event loop, asleep: waiting for the interpreter lock another thread holds (or another lock)"
            }.get(state, "event loop (Qt's own work, or waiting for the GIL)")


def _app_or_pyqtgraph(filename: str) -> bool:
    """A frame of the app's code or pyqtgraph's: not the standard library's, not another package's, not the bench's own
    (its entry and its event loop call lie under every sample)."""
    if filename.startswith((_STDLIB, "<frozen")):
        return False
    if "snreg_gui/tools/" in filename or filename.endswith("snreg_gui/bench.py"):
        return False
    return "site-packages" not in filename or "pyqtgraph" in filename


def _summary(frame) -> str:
    """The innermost frames of a stack as "file:line function" lines, the app's and its libraries' only ("" when it
    has none: the event loop)."""
    kept = [f"{entry.filename.rsplit('site-packages/', 1)[-1]}:{entry.lineno} {entry.name}"
            for entry in traceback.extract_stack(frame)
            if _app_or_pyqtgraph(entry.filename)]
    return " <- ".join(reversed(kept[-FRAMES_KEPT:]))
