"""CPU time per thread of this process, read from Linux's ``/proc/self/task``: where the live loop's cores go.

Why: the bench's pairs per second (issue 36) are bounded by what each thread costs on a machine of few cores: the GUI
thread, the acquisition worker (tracking, the insertion, session writes), the demo's renderer (the simulated camera,
not the app), the encoder (a process of its own, measured by the session). A thread's CPU time is what it costs
however loaded the machine is; wall times taken beside other work are not. Elsewhere than Linux there is no figure.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

_TASKS = Path("/proc/self/task")


def thread_cpu_s() -> dict[int, float]:
    """{native thread id: CPU seconds (user + system) so far} for every thread of this process; {} where
    ``/proc`` is missing."""
    times = {}
    for task in _tasks():
        spent = _stat_cpu_s(task / "stat")
        if spent is not None:                 # else the thread ended meanwhile
            times[int(task.name)] = spent
    return times


def process_cpu_s(pid: int) -> float | None:
    """CPU seconds (user + system, every thread's) process ``pid`` spent so far, e.g. the live loop's tracking process
    (issue 36); None when it is gone or ``/proc`` is missing."""
    return _stat_cpu_s(Path(f"/proc/{int(pid)}/stat"))


def _tasks() -> list[Path]:
    """This process's threads' ``/proc`` folders now; [] where ``/proc`` is missing."""
    try:
        return list(_TASKS.iterdir())
    except OSError:
        return []


def _stat_cpu_s(path: Path) -> float | None:
    """utime + stime of a ``/proc`` stat file, in seconds; None when it cannot be read."""
    ticks = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    try:
        stat = path.read_text()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2:].split()      # after the name, which may hold spaces
    return (int(fields[11]) + int(fields[12])) / ticks     # utime, stime (fields 14 and 15)


def cores_by_role(before: dict[int, float], after: dict[int, float], roles: dict[str, int | None],
                  seconds: float, process_s: float | None = None) -> dict[str, float]:
    """CPU seconds per second (cores) each named thread (``roles``: name -> native id, None when unknown) spent
    between two readings of :func:`thread_cpu_s` (``after``: each thread's latest, taken while it lived), the
    process's over the same time (``process_s``, CPU seconds, ended threads' included; else the threads' sum) as
    "process", and what the named threads leave of it as "other threads"; {} without readings."""
    if not after or seconds <= 0:
        return {}
    spent = {tid: after[tid] - before.get(tid, 0.0) for tid in after}
    figures = {name: round(spent[tid] / seconds, 3) for name, tid in roles.items() if tid is not None and tid in spent}
    total = sum(spent.values()) if process_s is None else process_s
    figures["other threads"] = round(max(total / seconds - sum(figures.values()), 0.0), 3)
    figures["process"] = round(total / seconds, 3)
    return figures


def thread_names() -> dict[int, str]:
    """{native thread id: name} for every thread of this process now: a Python thread's own name (e.g.
    "snreg-video-reports"), else the name Linux keeps for it (a Qt thread's, e.g. "QThread"); {} where ``/proc`` is
    missing."""
    names = {}
    for task in _tasks():
        try:
            names[int(task.name)] = (task / "comm").read_text().strip()
        except OSError:
            pass                               # ended meanwhile
    names.update({t.native_id: t.name for t in threading.enumerate() if t.native_id in names})
    return names


def cores_by_name(before: dict[int, float], after: dict[int, float], names: dict[int, str], seconds: float,
                  leave_out=()) -> dict[str, float]:
    """Cores (CPU s per s) the threads of each name spent between two readings of :func:`thread_cpu_s`, those in
    ``leave_out`` (native ids: the roles counted apart) left out, largest first; threads of one name summed (e.g. a
    thread pool's). Why: "other threads" of the bench (issue 36) said how much, not which."""
    if not after or seconds <= 0:
        return {}
    spent: dict[str, float] = {}
    for tid, cpu in after.items():
        if tid not in leave_out:
            name = names.get(tid, "?")
            spent[name] = spent.get(name, 0.0) + cpu - before.get(tid, 0.0)
    return {name: round(cpu / seconds, 3) for name, cpu in sorted(spent.items(), key=lambda kv: -kv[1])
            if cpu / seconds >= 0.0005}
