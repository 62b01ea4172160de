"""The GUI bench's probes: CPU per thread (``snreg_gui.tools.thread_cpu``) and where the GUI thread stalls
(``snreg_gui.tools.stall_stacks``). Neither test is timed: each waits on CPU spent or on a sample taken."""

import hashlib
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from conftest import poll
from snreg_gui.tools import stall_stacks
from snreg_gui.tools.stall_stacks import StallSampler, sched_times, stall_split, thread_state
from snreg_gui.tools.thread_cpu import cores_by_name, cores_by_role, process_cpu_s, thread_cpu_s, thread_names

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread CPU is read from /proc")


def _spin(cpu_s: float, ids: list) -> None:
    ids.append(threading.get_native_id())
    start = time.thread_time()
    while time.thread_time() - start < cpu_s:
        pass


@linux_only
def test_a_busy_thread_is_charged_its_cpu_and_an_idle_one_none():
    before = thread_cpu_s()
    busy_ids, idle_ids = [], []
    spun, release = threading.Event(), threading.Event()
    # it ends only once read after spinning: a reading takes a GIL hand-over per thread of the process, so while it
    # spins the last reading could come well before its end (it read 0.07 of 0.3 s in 2 runs of 5)
    busy = threading.Thread(target=lambda: (_spin(0.3, busy_ids), spun.set(), release.wait()))
    stop = threading.Event()
    idle = threading.Thread(target=lambda: (idle_ids.append(threading.get_native_id()), stop.wait()))
    busy.start()
    idle.start()
    assert poll(lambda: busy_ids and idle_ids)
    last = {}
    while busy.is_alive():                      # its last reading before it ends, as the bench keeps it
        done = spun.is_set()
        last.update(thread_cpu_s())
        if done:
            release.set()
        busy.join(0.05)
    last.update({tid: t for tid, t in thread_cpu_s().items() if tid == idle_ids[0]})
    stop.set()
    idle.join()
    cores = cores_by_role(before, last, {"busy": busy_ids[0], "idle": idle_ids[0], "gone": None}, 1.0)
    assert 0.2 <= cores["busy"] <= 1.0 and cores["idle"] < 0.05 and "gone" not in cores
    assert cores["process"] >= cores["busy"] and cores["other threads"] >= 0.0


@linux_only
def test_another_process_is_charged_its_cpu_and_a_gone_one_none():
    child = subprocess.Popen([sys.executable, "-c", "import time\nstart = time.process_time()\n"
                              "while time.process_time() - start < 0.3: pass\nprint(1, flush=True)\ninput()"],
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "1"            # it has spent its 0.3 s
        assert 0.25 <= process_cpu_s(child.pid) < 5.0            # (/proc counts in clock ticks)
    finally:
        child.stdin.close()
        child.wait()
    assert process_cpu_s(child.pid) is None


def test_cores_share_out_the_process_time_and_keep_the_rest_as_other_threads():
    cores = cores_by_role({1: 1.0, 2: 0.0}, {1: 3.0, 2: 1.0, 3: 0.5}, {"gui": 1, "worker": 2}, 2.0, process_s=5.0)
    assert cores == {"gui": 1.0, "worker": 0.5, "other threads": 1.0, "process": 2.5}
    assert cores_by_role({}, {}, {"gui": 1}, 2.0) == {}



def test_other_threads_are_told_apart_by_name_and_threads_of_one_name_summed():
    names = {1: "gui", 2: "pool", 3: "pool", 4: "snreg-video-reports", 5: "idle"}
    before = {1: 0.0, 2: 1.0, 3: 0.0, 4: 0.0, 5: 2.0}
    after = {1: 4.0, 2: 2.0, 3: 1.0, 4: 0.5, 5: 2.0, 6: 0.2}          # 6: a thread that began meanwhile, unnamed
    assert cores_by_name(before, after, names, 2.0, leave_out={1}) == {"pool": 1.0, "snreg-video-reports": 0.25,
                                                                        "?": 0.1}
    assert cores_by_name(before, {}, names, 2.0) == {}


@linux_only
def test_a_python_thread_is_named_as_python_named_it():
    stop = threading.Event()
    ids = []
    thread = threading.Thread(target=lambda: (ids.append(threading.get_native_id()), stop.wait()), name="snreg-probe")
    thread.start()
    try:
        assert poll(lambda: ids)
        assert thread_names()[ids[0]] == "snreg-probe"
        assert threading.get_native_id() in thread_names()
    finally:
        stop.set()
        thread.join()

def _stalled_here(sampler: StallSampler) -> None:
    """Hold this thread in Python (so the sampler gets its turns) until the sampler has seen it here, 30 s at most."""
    deadline = time.monotonic() + 30.0
    while not any("_stalled_here" in stack for stack, _ in sampler.top()) and time.monotonic() < deadline:
        pass


def test_the_sampler_names_the_function_the_stalled_thread_is_in():
    ticks = [time.perf_counter() - 1.0]                  # the heartbeat is a second late
    sampler = StallSampler(lambda: ticks[-1], late_ms=20.0)
    try:
        _stalled_here(sampler)
    finally:
        sampler.stop()
    (stack, count), *_ = sampler.top()
    assert "_stalled_here" in stack and count >= 1


def test_the_sampler_samples_nothing_before_the_first_tick():
    asked = []
    sampler = StallSampler(lambda: asked.append(1), late_ms=0.0)     # no tick yet (None), however late
    assert poll(lambda: len(asked) >= 5)
    sampler.stop()
    assert sampler.top() == []


def _seen(sampler: StallSampler, state: str) -> bool:
    return any(stack.startswith(f"event loop, {state}:") for stack, _ in sampler.top())


@linux_only
def test_the_sampler_tells_a_thread_asleep_outside_the_app_from_one_running(monkeypatch, tmp_path):
    """Issue 36: a stall outside the app's code was one line, "Qt's own work, or waiting for the GIL"; the thread's
    state then tells them apart: asleep (waiting for a lock another thread holds) or running."""
    monkeypatch.setattr(stall_stacks, "_summary", lambda frame: "")      # no frame of the app's: Qt's event loop
    sampler = StallSampler(lambda: time.perf_counter() - 1.0, late_ms=20.0)
    data = bytes(8_000_000)
    deadline = time.monotonic() + 30.0
    try:
        while not _seen(sampler, "asleep") and time.monotonic() < deadline:
            time.sleep(0.05)                                      # asleep, the interpreter lock let go
        while not _seen(sampler, "running") and time.monotonic() < deadline:
            hashlib.sha256(data).digest()                         # running, the lock let go while it hashes
    finally:
        sampler.stop()
    assert _seen(sampler, "asleep") and _seen(sampler, "running")
    assert all(stack.startswith("event loop") for stack, _ in sampler.top())
    assert thread_state(tmp_path / "no-such-thread" / "stat") == ""


def test_a_stall_is_split_into_running_waiting_for_a_cpu_and_asleep():
    """Issue 36: on a loaded machine a stall may be the GUI thread waiting for a CPU; the scheduler's times read at
    each tick split each gap over the target."""
    ticks = [0.0, 0.010, 0.110, 0.120, 0.170]                    # gaps 10, 100, 10 and 50 ms
    sched = [(0.0, 0.0), (0.005, 0.0), (0.025, 0.070), (0.030, 0.070), (0.060, 0.075)]
    split = stall_split(ticks, sched, over_ms=33.0)
    assert split["stalls"] == 2 and split["ms"] == pytest.approx(150.0)
    assert split["longest"] == pytest.approx({"ms": 100.0, "running_ms": 20.0, "waiting_for_cpu_ms": 70.0,
                                              "asleep_ms": 10.0})
    assert (split["running_ms"], split["waiting_for_cpu_ms"], split["asleep_ms"]) == pytest.approx((50.0, 75.0, 25.0))
    capped = stall_split(ticks[:3], [(0.0, 0.0), (0.0, 0.0), (0.080, 0.050)], 33.0)   # read a moment off the ticks
    assert capped["running_ms"] == 80.0 and capped["waiting_for_cpu_ms"] == 20.0 and capped["asleep_ms"] == 0.0
    assert stall_split(ticks, sched[:-1], 33.0) is None and stall_split(ticks, sched, 200.0) is None


@linux_only
def test_the_scheduler_times_of_a_thread_grow_as_it_runs(tmp_path):
    times = sched_times(Path(f"/proc/self/task/{threading.get_native_id()}/schedstat"))
    if times is None:
        pytest.skip("this kernel keeps no scheduler statistics")
    _spin(0.05, [])
    later = sched_times(Path(f"/proc/self/task/{threading.get_native_id()}/schedstat"))
    assert later[0] - times[0] >= 0.04 and later[1] >= times[1]
    assert sched_times(tmp_path / "schedstat") is None
