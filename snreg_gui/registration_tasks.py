"""Keeps the :class:`~snreg_gui.workers.Worker` objects a registration widget started alive until they end.

Why: a Worker must stay referenced while its thread runs (workers.py), and a widget that starts several
(file loading, segmentation, registration, export) would otherwise repeat the same bookkeeping. This is not
a thread helper: it only starts Workers with their signals connected and drops them once their threads end.

>>> tasks = WorkerSet()
>>> tasks.start(read_nodes, path, returned=self._show_nodes, errored=self._show_problem)
>>> tasks.shutdown()                   # on close: ask generators to stop, wait for every thread

:func:`sentence` turns a worker's error message into the one sentence the widgets show.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from PySide6.QtCore import QCoreApplication

from snreg_gui.workers import Worker


class WorkerSet:
    """The running workers of one widget."""

    def __init__(self):
        self._workers: list[Worker] = []

    def start(self, fn: Callable, *args, returned: Callable, errored: Callable) -> Worker:
        """Run ``fn(*args)`` in a Worker; ``returned(value)`` or ``errored(sentence)`` follow on the GUI thread."""
        self._workers = [w for w in self._workers if w.running]
        worker = Worker(fn, *args)
        worker.returned.connect(returned)
        worker.errored.connect(errored)
        self._workers.append(worker)
        return worker.start()

    def shutdown(self, timeout_ms: int = 10_000) -> None:
        """Stop and wait for every worker (for closing the window and for tests).

        A Worker's thread is told to quit through a signal queued to this (the GUI) thread, so events are
        processed while waiting; a worker still running at the timeout stays referenced rather than being
        destroyed with its thread alive.
        """
        for worker in self._workers:
            worker.quit()
        deadline = time.monotonic() + timeout_ms / 1000
        for worker in self._workers:
            while not worker.wait(10) and time.monotonic() < deadline:
                QCoreApplication.processEvents()
        self._workers = [w for w in self._workers if w.running]


def sentence(message: str) -> str:
    """A worker's error message as one sentence: capital first letter, full stop at the end."""
    message = message.strip()
    if not message:
        return "Something went wrong; try again."
    message = message[0].upper() + message[1:]
    return message if message.endswith((".", "!", "?")) else message + "."
