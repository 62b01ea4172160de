"""Long work off the GUI thread: a function or generator run in its own QThread, results as signals.

Why: calibration, registration, SPECT segmentation and live corner detection take from tens of
milliseconds to seconds, and the GUI thread must never block (DESIGN.md §5). Modelled on napari's
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


class Worker(QObject):
    """Runs ``fn(*args, **kwargs)`` once in a new thread. If it returns a generator, its items are emitted as
    ``yielded`` until it ends (its return value is ``returned``) or :meth:`quit` is called.

    ``errored`` carries one sentence (the exception's message, prefixed by its type only when the message
    is empty); ``finished`` always comes last, after which the thread is gone.
    """

    yielded = Signal(object)
    returned = Signal(object)
    errored = Signal(str)
    finished = Signal()

    def __init__(self, fn: Callable, *args, **kwargs):
        super().__init__()
        self._fn, self._args, self._kwargs = fn, args, kwargs
        self._quit = False
        self._thread: QThread | None = None

    def start(self) -> "Worker":
        """Move to a new thread and run there; connect the signals before calling this."""
        self._thread = QThread()
        self.moveToThread(self._thread)
        self._thread.started.connect(self._run)
        # direct: the thread ends even when the GUI event loop is not running (shutdown, tests)
        self.finished.connect(self._thread.quit, Qt.ConnectionType.DirectConnection)
        self._thread.start()
        return self

    def quit(self) -> None:
        """Ask a generator to stop after its current item (thread-safe; a plain function runs to its end)."""
        self._quit = True

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.isRunning()

    def wait(self, timeout_ms: int = 10_000) -> bool:
        """Block until the thread has ended (for shutdown and tests); True when it has."""
        return self._thread is None or self._thread.wait(timeout_ms)

    @Slot()
    def _run(self) -> None:
        try:
            result = self._fn(*self._args, **self._kwargs)
            if inspect.isgenerator(result):
                result = self._drain(result)
            if not self._quit or result is not None:
                self.returned.emit(result)
        except Exception as err:          # noqa: BLE001 - every failure must reach the user, never kill the app
            self.errored.emit(str(err) or type(err).__name__)
        finally:
            self.finished.emit()

    def _drain(self, generator):
        try:
            while not self._quit:
                self.yielded.emit(next(generator))
        except StopIteration as stop:
            return stop.value
        generator.close()
        return None
