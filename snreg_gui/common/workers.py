"""Long work off the GUI thread: a function or generator run in its own QThread, results as signals.

Why: calibration, registration, SPECT segmentation and live corner detection take from tens of
milliseconds to seconds, and the GUI thread must never block (docs/design.md, Habits). Modelled on napari's
generator workers: connect ``yielded``/``returned``/``errored``/``finished`` first, then :meth:`Worker.start`.
A generator is a loop that yields progress or live results and may be asked to stop between yields.

>>> worker = Worker(calibrate_stereo, left, right, board)
>>> worker.returned.connect(show_result); worker.errored.connect(status_bar.showMessage)
>>> worker.start()
"""

from __future__ import annotations

import inspect
from collections.abc import Callable

from PySide6.QtCore import QObject, Qt, QThread, Signal, Slot


class _Job(QObject):
    """The part that moves to the worker thread and runs there; its signals are relayed by :class:`Worker`."""

    yielded = Signal(object)
    returned = Signal(object)
    errored = Signal(str)
    finished = Signal()

    def __init__(self, fn: Callable, args: tuple, kwargs: dict):
        super().__init__()
        self.fn, self.args, self.kwargs = fn, args, kwargs
        self.quit_requested = False

    @Slot()
    def run(self) -> None:
        try:
            result = self.fn(*self.args, **self.kwargs)
            if inspect.isgenerator(result):
                result = self._drain(result)
            if not self.quit_requested or result is not None:
                self.returned.emit(result)
        except Exception as err:          # noqa: BLE001 - every failure must reach the user, never kill the app
            self.errored.emit(str(err) or type(err).__name__)
        finally:
            self.finished.emit()

    def _drain(self, generator):
        try:
            while not self.quit_requested:
                self.yielded.emit(next(generator))
        except StopIteration as stop:
            return stop.value
        generator.close()
        return None


class Worker(QObject):
    """Runs ``fn(*args, **kwargs)`` once in a new thread. If it returns a generator, its items are emitted as
    ``yielded`` until it ends (its return value is ``returned``) or :meth:`quit` is called.

    ``errored`` carries one sentence (the exception's message, or its type when the message is empty);
    ``finished`` always comes last. Every signal is emitted in the thread that made the Worker (the GUI
    thread), so any slot, lambda or plain function connected to it runs there and may touch widgets.
    Keep a reference to the Worker while it runs.
    """

    yielded = Signal(object)
    returned = Signal(object)
    errored = Signal(str)
    finished = Signal()

    def __init__(self, fn: Callable, *args, **kwargs):
        super().__init__()
        self._job = _Job(fn, args, kwargs)
        self._thread: QThread | None = None
        self._delivered = False
        self.finished.connect(self._all_delivered)

    def start(self) -> "Worker":
        """Run in a new thread; connect the signals before calling this."""
        self._thread = QThread()
        self._job.moveToThread(self._thread)
        self._thread.started.connect(self._job.run)
        # direct: the thread ends even when the GUI event loop is not running (shutdown, tests)
        self._job.finished.connect(self._thread.quit, Qt.ConnectionType.DirectConnection)
        queued = Qt.ConnectionType.QueuedConnection      # re-emitted in this object's (the GUI) thread
        for name in ("yielded", "returned", "errored", "finished"):
            getattr(self._job, name).connect(getattr(self, name), queued)
        self._thread.start()
        return self

    def quit(self) -> None:
        """Ask a generator to stop after its current item (thread-safe; a plain function runs to its end)."""
        self._job.quit_requested = True

    @property
    def running(self) -> bool:
        """Its thread is still running."""
        return self._thread is not None and self._thread.isRunning()

    @property
    def pending(self) -> bool:
        """Started, and not yet both delivered ``finished`` here and ended its thread: while pending, a Worker must
        stay referenced (results may be on their way to the slots; a QThread deleted while it runs aborts)."""
        return self._thread is not None and not self._delivered

    @Slot()
    def _all_delivered(self) -> None:
        self._thread.wait()         # the thread ends right after emitting ``finished``: at most a moment here
        self._delivered = True

    def wait(self, timeout_ms: int = 10_000) -> bool:
        """Block until the thread has ended (for shutdown and tests); True when it has. Signals still queued for
        this thread are delivered when its event loop next runs."""
        return self._thread is None or self._thread.wait(timeout_ms)


class WorkerSet:
    """The Workers of one widget, kept referenced until their last signal has been delivered (a Worker
    dropped earlier would take its queued result with it).

    >>> tasks = WorkerSet()
    >>> tasks.start(read_nodes, path, returned=self._show_nodes, errored=self._show_problem)
    >>> tasks.shutdown()                   # on close: ask generators to stop, wait for every thread
    """

    def __init__(self):
        self._workers: list[Worker] = []
        self._closed = False

    def run(self, worker: Worker) -> Worker | None:
        """Start ``worker`` (its signals connected) and keep it until it has ended; after :meth:`shutdown` nothing
        starts (a signal queued before the window closed must not leave a thread running past it), and None is
        returned."""
        if self._closed:
            return None
        self._workers = [w for w in self._workers if w.pending]
        self._workers.append(worker)
        return worker.start()

    def start(self, fn: Callable, *args, returned: Callable, errored: Callable) -> Worker | None:
        """Run ``fn(*args)`` in a Worker; ``returned(value)`` or ``errored(sentence)`` follow on the GUI thread."""
        worker = Worker(fn, *args)
        worker.returned.connect(returned)
        worker.errored.connect(errored)
        return self.run(worker)

    @property
    def running(self) -> bool:
        return any(worker.running for worker in self._workers)

    def shutdown(self, timeout_ms: int = 10_000) -> None:
        """Ask every generator to stop and wait for every thread (closing a window, tests). The workers stay
        referenced, so their last signals are still delivered when the event loop next runs."""
        self._closed = True
        for worker in self._workers:
            worker.quit()
        for worker in self._workers:
            worker.wait(timeout_ms)


def release_finished(current: Worker | None, finished: Worker) -> bool:
    """On a Worker's ``finished``: True when it is ``current`` and its thread has ended, so the last reference
    may go (a QThread deleted while running aborts); False for a worker already waited for by a shutdown."""
    return current is not None and finished is current and current.wait()


class LiveLoop(QObject):
    """A generator ``loop(*args)`` run in a Worker that can be started and stopped as pages come and go (a live
    capture); each item it yields arrives as ``frame_ready``.

    Never blocks but in :meth:`shutdown`: a stop takes effect after the current item, and a start asked for
    meanwhile runs the loop again only once the old one has ended (a camera opens only once). ``stopped`` says
    why the loop ended by itself (what it returned, e.g. the source's problem, or why it failed).
    """

    frame_ready = Signal(object)
    stopped = Signal(str)

    def __init__(self, loop: Callable, *args, parent: QObject | None = None):
        super().__init__(parent)
        self._loop, self._args = loop, args
        self._worker: Worker | None = None
        self._wanted = False
        self._stopping = False

    @property
    def running(self) -> bool:
        return self._worker is not None

    def start(self) -> None:
        self._wanted = True
        if self._worker is None:
            worker = Worker(self._loop, *self._args)
            worker.yielded.connect(self.frame_ready)
            worker.returned.connect(self._ended)
            worker.errored.connect(self._failed)
            worker.finished.connect(self._finished)
            self._worker = worker.start()

    def stop(self) -> None:
        self._wanted = False
        if self._worker is not None:
            self._stopping = True
            self._worker.quit()

    def shutdown(self) -> None:
        """Stop and wait until the source is closed and the thread has ended."""
        self.stop()
        if self._worker is not None:
            self._worker.wait()
            self._worker = None

    def _ended(self, problem: str) -> None:
        self._wanted = False
        self.stopped.emit(problem)

    def _failed(self, message: str) -> None:
        self._wanted = False
        self.stopped.emit(message)

    def _finished(self) -> None:
        if not release_finished(self._worker, self.sender()):
            return
        self._worker, restart, self._stopping = None, self._wanted and self._stopping, False
        if restart:
            self.start()


class FitRunner(QObject):
    """Runs ``fit`` on the latest arguments in a Worker, one run at a time; arguments that arrive meanwhile wait for
    the next run, and only the newest wait (a live fit that must keep up with its samples).

    ``fitted`` carries the result of the newest arguments given since :meth:`reset`; older results are dropped.
    """

    fitted = Signal(object)
    failed = Signal(str)

    def __init__(self, fit: Callable, parent: QObject | None = None):
        super().__init__(parent)
        self._fit = fit
        self._worker: Worker | None = None
        self._pending: tuple | None = None
        self._generation = self._running_generation = 0

    @property
    def running(self) -> bool:
        return self._worker is not None

    def request(self, *args) -> None:
        self._pending = args
        if self._worker is None:
            self._launch()

    def reset(self) -> None:
        self._pending = None
        self._generation += 1

    def shutdown(self) -> None:
        self._pending = None
        if self._worker is not None:
            self._worker.wait()
            self._worker = None

    def _launch(self) -> None:
        args, self._pending = self._pending, None
        self._running_generation = self._generation
        worker = Worker(self._fit, *args)
        worker.returned.connect(self._returned)
        worker.errored.connect(self.failed)
        worker.finished.connect(self._finished)
        self._worker = worker.start()

    def _returned(self, fit) -> None:
        if self._running_generation == self._generation:
            self.fitted.emit(fit)

    def _finished(self) -> None:
        if not release_finished(self._worker, self.sender()):
            return
        self._worker = None
        if self._pending is not None:
            self._launch()



def sentence(message: str) -> str:
    """A worker's error message as one sentence: capital first letter, full stop at the end."""
    message = message.strip()
    if not message:
        return "Something went wrong; try again."
    message = message[0].upper() + message[1:]
    return message if message.endswith((".", "!", "?")) else message + "."
