"""``snreg simulate``'s worker processes: never more than the CPUs, and none outlives a killed study."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from snreg.simulation.workers import cpu_count, worker_count


def _children(pid: int) -> set[int]:
    """The processes whose parent is ``pid`` (Linux /proc)."""
    found = set()
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                found.add(int(entry.name))
    return found


def _alive(pids: set[int]) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            alive.add(pid)
    return alive


def test_never_more_workers_than_cpus():
    assert worker_count(0) == cpu_count() and worker_count(100_000) == cpu_count() and worker_count(1) == 1


def test_killing_a_study_leaves_no_worker_behind(tmp_path):
    study = subprocess.Popen([sys.executable, "-m", "snreg.cli", "simulate", "--reps", "10000", "--methods", "icp",
                              "--workers", "0", "--quiet", "-o", str(tmp_path / "report")],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120.0
    workers = set()
    while len(workers) < min(2, cpu_count()) and time.monotonic() < deadline and study.poll() is None:
        time.sleep(0.1)
        workers = _children(study.pid)
    assert 1 <= len(workers) <= cpu_count()
    os.kill(study.pid, signal.SIGKILL)            # nothing of the parent runs any more to stop them
    study.wait()
    deadline = time.monotonic() + 10.0
    while _alive(workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(workers)
