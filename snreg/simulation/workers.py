"""Worker processes that end with the process that started them, and never more of them than CPUs.

Why: ``ProcessPoolExecutor`` workers outlive a parent killed with SIGKILL (nothing runs in the parent to stop them),
each still busy with a block of the study, and ask for as many processes as ``max_workers`` says. Each worker here
asks the kernel to kill it when its parent dies (Linux ``prctl(PR_SET_PDEATHSIG)``) and also watches its parent
itself (any POSIX system: a reparented worker exits within a second).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import signal
import threading
import time

__all__ = ["cpu_count", "end_with_parent", "worker_count"]

_PR_SET_PDEATHSIG = 1
_WATCH_S = 0.5


def cpu_count() -> int:
    """The CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def worker_count(asked: int) -> int:
    """Processes for ``asked`` workers (0: one per CPU), never more than the CPUs."""
    return max(1, min(asked or cpu_count(), cpu_count()))


def end_with_parent(parent: int) -> None:
    """A pool initializer: end this worker when process ``parent`` (the one that started it) ends."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        pass                                     # not Linux: the watch below does it
    if os.getppid() != parent:                  # the parent died before the request took effect
        os._exit(1)
    threading.Thread(target=_watch, args=(parent,), name="snreg-parent-watch", daemon=True).start()


def _watch(parent: int) -> None:
    while os.getppid() == parent:
        time.sleep(_WATCH_S)
    os._exit(1)
