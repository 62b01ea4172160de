"""One client of the live link and the link's counters: the server thread's bookkeeping per connection.

Why apart from :mod:`snreg.workflow.live_link`: what a connection holds (the message being written, the newest message
waiting per device: latest wins) and how it is written without blocking is the same whatever the link serves; the
link decides what to send and when.
"""

from __future__ import annotations

import socket
from dataclasses import dataclass

__all__ = ["Client", "LinkStats"]


@dataclass(frozen=True)
class LinkStats:
    """Clients now, messages waiting for them now (at most one per device and client), and counters since the start:
    clients ever, messages written whole, messages replaced by a newer one of their device before a client took
    them (latest wins), clients dropped for stalling or gone, connections refused (over ``max_clients``, or when the
    process ran out of file descriptors), and the CPU seconds the server thread has used (packing and writing: the
    link's own cost besides the callers' calls)."""

    clients: int
    waiting: int
    clients_seen: int
    messages_sent: int
    messages_replaced: int
    dropped_stalled: int
    disconnected: int
    refused: int
    cpu_s: float


class Client:
    """One connection, owned by the server thread: the message being written and the newest waiting per device."""

    def __init__(self, sock: socket.socket, address: str):
        self.sock, self.address = sock, address
        self.outbox: dict[str, bytes] = {}
        self.current: memoryview | None = None
        self.blocked_since: float | None = None

    @property
    def waiting(self) -> bool:
        return self.current is not None or bool(self.outbox)

    def queue(self, device: str, payload: bytes) -> bool:
        """Make ``payload`` the next message of ``device``; True when it replaced one not yet taken."""
        replaced = self.outbox.pop(device, None) is not None
        self.outbox[device] = payload
        return replaced

    def write(self, now: float) -> int:
        """Write what the socket takes now; returns the messages completed. OSError when the client is gone."""
        done = 0
        while self.waiting:
            if self.current is None:
                device = next(iter(self.outbox))
                self.current = memoryview(self.outbox.pop(device))
            try:
                sent = self.sock.send(self.current)
            except (BlockingIOError, InterruptedError):
                sent = 0
            if sent == 0:
                self.blocked_since = self.blocked_since or now
                return done
            self.blocked_since = None
            self.current = self.current[sent:] if sent < len(self.current) else None
            done += self.current is None
        return done
