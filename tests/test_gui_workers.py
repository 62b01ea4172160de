"""The shared worker (snreg_gui.common.workers.Worker): results, generators, errors and stopping, off the GUI thread."""

import threading

import pytest

from snreg_gui.common.workers import Worker, WorkerSet


def run(qtbot, worker, timeout=5_000):
    events = {"yielded": [], "returned": [], "errored": []}
    for name, store in events.items():
        getattr(worker, name).connect(store.append)
    with qtbot.waitSignal(worker.finished, timeout=timeout):
        worker.start()
    assert worker.wait(2_000)
    return events


def test_a_function_runs_in_another_thread_and_its_result_arrives_in_this_one(qtbot):
    ran_in, received_in = [], []
    worker = Worker(lambda a, b: ran_in.append(threading.current_thread()) or a + b, 2, b=3)
    worker.returned.connect(lambda _: received_in.append(threading.current_thread()))   # a lambda, not a slot
    assert not worker.pending
    events = run(qtbot, worker)
    assert not worker.pending                                # "finished" came, so everything before it did
    assert events == {"yielded": [], "returned": [5], "errored": []}
    assert ran_in[0] is not threading.main_thread()
    assert received_in == [threading.main_thread()]          # widgets may be touched from any connected callable


def test_a_generator_yields_then_returns(qtbot):
    def count(n):
        for k in range(n):
            yield k
        return "done"

    events = run(qtbot, Worker(count, 4))
    assert events["yielded"] == [0, 1, 2, 3] and events["returned"] == ["done"]


def test_an_exception_becomes_one_sentence(qtbot):
    def fail():
        raise ValueError("the file is not a calibration; choose another")

    events = run(qtbot, Worker(fail))
    assert events["errored"] == ["the file is not a calibration; choose another"] and events["returned"] == []


@pytest.mark.parametrize("ask_to_quit_after", [1, 3])
def test_quit_stops_an_endless_generator(qtbot, ask_to_quit_after):
    worker = None

    def endless():
        k = 0
        while True:
            if k == ask_to_quit_after:
                worker.quit()
            yield k
            k += 1

    worker = Worker(endless)
    events = run(qtbot, worker)
    assert events["yielded"] == list(range(ask_to_quit_after + 1)) and events["errored"] == []
    assert not worker.running


def test_a_worker_set_keeps_its_workers_until_shutdown_ends_them(qtbot):
    from snreg_gui.common.workers import WorkerSet

    def endless():
        while True:
            yield 0

    results = []
    tasks = WorkerSet()
    tasks.start(lambda: 7, returned=results.append, errored=results.append)
    live = Worker(endless)
    tasks.run(live)
    assert tasks.running
    tasks.shutdown(5_000)
    assert not tasks.running and not live.running
    qtbot.waitUntil(lambda: results == [7], timeout=2_000)   # a result queued before shutdown is not lost


def test_a_worker_set_starts_nothing_after_shutdown(qtbot):
    tasks = WorkerSet()
    results = []
    tasks.start(lambda: 1, returned=results.append, errored=results.append)
    qtbot.waitUntil(lambda: results == [1], timeout=5_000)
    tasks.shutdown()
    assert tasks.start(lambda: 2, returned=results.append, errored=results.append) is None
    qtbot.wait(100)
    assert results == [1] and not tasks.running
