"""Who the live link lets in: at most ``max_clients``, a polite refusal for the next, and no end at ``EMFILE``.

Why its own module: a process that runs out of file descriptors (a flood of idle connections, a leak elsewhere) makes
``accept()`` fail with ``EMFILE`` while the connection stays queued, so the listener stays readable: a server that
let that error through stopped serving for good, and one that ignored it would spin. The door keeps one descriptor in
reserve, gives it up to take the waiting connection and close it, and stops listening for ``ACCEPT_PAUSE_S``; the
clients already served keep receiving everything meanwhile. A connection over the cap gets one Status message saying
why, then is closed, so a viewer sees the reason rather than a silent hang-up.
"""

from __future__ import annotations

import errno
import logging
import os
import selectors
import socket
import time

from snreg.workflow import live_messages as msg

__all__ = ["Door", "MAX_CLIENTS", "ACCEPT_PAUSE_S"]

log = logging.getLogger(__name__)

MAX_CLIENTS = 16                # 3D Slicer and a few viewers; more are refused politely (a Status line, then closed)
ACCEPT_PAUSE_S = 0.5            # out of file descriptors: accepting pauses this long (the clients served keep going)
_ACCEPTS_PER_ROUND = 64         # a flood of connections cannot hold up the clients already served
_OUT_OF_DESCRIPTORS = (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM)


class Door:
    """Accepts connections on ``listener`` (non-blocking, registered in the server's selector with ``data``) for a
    server that holds ``served()`` clients; :meth:`accept` returns the new ones to serve. Server thread only."""

    def __init__(self, listener: socket.socket, max_clients: int = MAX_CLIENTS, data=None):
        self.listener, self.max_clients, self._data = listener, max(1, int(max_clients)), data
        self.refused = 0
        self._paused_until = 0.0
        try:
            self._reserve: int | None = os.open(os.devnull, os.O_RDONLY)
        except OSError:
            self._reserve = None

    def accept(self, selector, served: int) -> list[tuple[socket.socket, str]]:
        """The connections waiting now that may be served (socket, "host:port"); the rest refused in words."""
        new = []
        for _ in range(_ACCEPTS_PER_ROUND):
            try:
                sock, peer = self.listener.accept()
            except (BlockingIOError, InterruptedError):
                break
            except OSError as err:
                if err.errno not in _OUT_OF_DESCRIPTORS:
                    raise
                self._out_of_descriptors(selector)
                break
            if served + len(new) >= self.max_clients:
                self._refuse(sock, f"snreg: {served + len(new)} clients are connected already (at most "
                                   f"{self.max_clients}); this connection is closed")
            else:
                new.append((sock, f"{peer[0]}:{peer[1]}"))
        return new

    def timeout(self, wait: float) -> float:
        """``wait`` shortened to when accepting resumes, if it is paused."""
        return min(wait, self._paused_until - time.monotonic()) if self._paused_until else wait

    def resume_if_due(self, selector) -> None:
        """Listen again once the pause after ``EMFILE`` is over."""
        if self._paused_until and time.monotonic() >= self._paused_until:
            self._paused_until = 0.0
            selector.register(self.listener, selectors.EVENT_READ, self._data)

    def close(self) -> None:
        if self._reserve is not None:
            os.close(self._reserve)
            self._reserve = None

    def _refuse(self, sock: socket.socket, why: str) -> None:
        """Tell a connection why it is not served (one Status message, if its buffer takes it) and close it."""
        self.refused += 1
        try:
            sock.setblocking(False)
            sock.send(msg.status(why))
        except OSError:
            pass
        sock.close()

    def _out_of_descriptors(self, selector) -> None:
        log.warning("live link: out of file descriptors; a connection was refused and accepting pauses %.1f s",
                    ACCEPT_PAUSE_S)
        if self._reserve is not None:
            os.close(self._reserve)
            self._reserve = None
            try:
                sock, _ = self.listener.accept()
                sock.close()
            except OSError:
                pass
            try:
                self._reserve = os.open(os.devnull, os.O_RDONLY)
            except OSError:
                self._reserve = None
        self.refused += 1
        selector.unregister(self.listener)
        self._paused_until = time.monotonic() + ACCEPT_PAUSE_S
