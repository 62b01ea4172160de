"""The live link's server thread: every socket of :class:`~snreg.workflow.live_link.LiveLink` is handled here.

Why a module of its own: the link has two sides that share only the state under its lock. The callers' side
(:mod:`snreg.workflow.live_link`) puts the newest state of each device into ``_pending`` and wakes this thread; this
side accepts clients, packs what changed (latest wins), writes without blocking, drops clients that leave or stall,
and recomputes the ``Status`` line. :class:`LinkServer` is a mixin of ``LiveLink``: it reads the attributes that
``LiveLink.__init__`` sets (``_lock``, ``_pending``, ``_woken``, ``_points``, ``_frames``, ``_fixes``,
``_last_frame``, ``_action``, ``_counts``, ``_clients``, ``_current``, the listener, the wake-up pair and the door).
"""

from __future__ import annotations

import logging
import selectors
import socket
import time

from snreg.workflow import live_messages as msg
from snreg.workflow.live_client import Client

log = logging.getLogger("snreg.workflow.live_link")      # one logger for the whole link, as before the split

STATUS_PERIOD_S = 1.0           # the Status string is recomputed (and sent if it changed) this often
STATE = (msg.INTRAOP_NODES, msg.PREOP_NODES, msg.INTRAOP_LANDMARKS, msg.PREOP_LANDMARKS, msg.TROCAR_TO_RAS,
         msg.MISSING_HOT_SPOTS, msg.STATUS)                                  # re-sent whole to every new client
STORED = (msg.INTRAOP_NODES, msg.INTRAOP_LANDMARKS)     # the stored points' lists, by kind
PREOP = (msg.PREOP_NODES, msg.PREOP_LANDMARKS)
LISTEN, WAKE = "listen", "wake"


class LinkServer:
    """The server thread's half of :class:`~snreg.workflow.live_link.LiveLink` (its ``_serve`` is the thread's
    target); never called from the callers' threads."""

    def _serve(self) -> None:
        selector = selectors.DefaultSelector()
        selector.register(self._listener, selectors.EVENT_READ, LISTEN)
        selector.register(self._wake_r, selectors.EVENT_READ, WAKE)
        self._health = msg.StreamHealth()
        next_status = time.monotonic() + STATUS_PERIOD_S
        try:
            while not self._closing:
                self._door.resume_if_due(selector)
                for key, mask in selector.select(max(0.0, self._door.timeout(next_status - time.monotonic()))):
                    if key.data == LISTEN:
                        self._accept(selector)
                    elif key.data == WAKE:
                        self._drain_wake()
                    elif mask & selectors.EVENT_READ:
                        self._read(selector, key.data)
                now = time.monotonic()
                if now >= next_status:
                    with self._lock:
                        self._pending[msg.STATUS] = True
                    next_status = now + STATUS_PERIOD_S
                self._distribute(now)
                self._write_all(selector, now)
                self._cpu_s = time.thread_time()
        except Exception:                                        # the link must not die silently
            log.exception("the live link stopped")
        finally:
            for client in list(self._clients):
                self._drop(selector, client, None)
            selector.close()
            for sock in (self._listener, self._wake_r, self._wake_w):
                sock.close()
            self._door.close()

    def _accept(self, selector) -> None:
        for sock, address in self._door.accept(selector, len(self._clients)):
            try:
                sock.setblocking(False)
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, self._send_buffer)
            except OSError:
                sock.close()
                continue
            client = Client(sock, address)
            for device in STATE:
                if device in self._current:
                    client.queue(device, self._current[device])
            self._clients.append(client)
            selector.register(sock, selectors.EVENT_READ, client)
            self._set_count(+1)
            self._connected.set()

    def _read(self, selector, client: Client) -> None:
        """Take and ignore what a client sends (Slicer may query or echo); an empty read means it has gone."""
        try:
            data = client.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._drop(selector, client, "disconnected")

    def _distribute(self, now: float) -> None:
        with self._lock:
            pending, self._pending, self._woken = self._pending, {}, False
            frames, fixes, last_frame, action = self._frames, self._fixes, self._last_frame, self._action
            n_nodes, n_landmarks = (len(self._points[device]) for device in STORED)
        for device, data in pending.items():
            if data is None:                                 # cleared (clear_registration): no longer current state
                self._current.pop(device, None)
                continue
            try:
                payload = self._pack(device, data, now, frames, fixes, last_frame, action, n_nodes, n_landmarks)
            except (ValueError, TypeError) as err:                  # bad data from a caller: say so, keep serving
                log.warning("live link: %s not sent: %s", device, err)
                continue
            if payload is None:
                continue
            if device in STATE:
                self._current[device] = payload
            for client in self._clients:
                if client.queue(device, payload):
                    self._count("messages_replaced")

    def _pack(self, device, data, now, frames, fixes, last_frame, action, n_nodes, n_landmarks) -> bytes | None:
        if device == msg.PROBE_POSE:
            return msg.probe_pose(*data)
        if device in STORED or device == msg.MISSING_HOT_SPOTS:
            return msg.point_list(device, *data)
        if device in PREOP:
            return msg.preop_points(*data, device=device)
        if device == msg.TROCAR_TO_RAS:
            return msg.trocar_to_ras(data)
        landmarks = f", {n_landmarks} landmark{'s' if n_landmarks != 1 else ''}" if n_landmarks else ""
        text = f"{self._health.describe(now, frames, fixes, last_frame)}; {n_nodes} stored{landmarks}; last: {action}"
        if self._current.get(msg.STATUS) is not None and text == self._health.last_text:
            return None
        self._health.last_text = text
        return msg.status(text)

    def _write_all(self, selector, now: float) -> None:
        for client in list(self._clients):
            try:
                done = client.write(now)
            except OSError:
                self._drop(selector, client, "disconnected")
                continue
            self._count("messages_sent", done)
            if client.blocked_since is not None and now - client.blocked_since > self._stall_drop_s:
                log.warning("live link: dropped %s, which took nothing for %.0f s", client.address, self._stall_drop_s)
                self._drop(selector, client, "dropped_stalled")
                continue
            events = selectors.EVENT_READ | (selectors.EVENT_WRITE if client.waiting else 0)
            if selector.get_key(client.sock).events != events:
                selector.modify(client.sock, events, client)
        waiting = sum(len(c.outbox) + (c.current is not None) for c in self._clients)
        with self._lock:
            self._waiting = waiting
            if not self._pending and not waiting:
                self._drained.set()

    def _drop(self, selector, client: Client, reason: str | None) -> None:
        self._clients.remove(client)
        selector.unregister(client.sock)
        client.sock.close()
        if reason:
            self._count(reason)
        self._set_count(-1)

    def _drain_wake(self) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except (BlockingIOError, InterruptedError):
            pass

    def _count(self, name: str, n: int = 1) -> None:
        with self._lock:
            self._counts[name] += n

    def _set_count(self, change: int) -> None:
        with self._lock:
            self._client_count += change
            if change > 0:
                self._counts["clients_seen"] += 1
        if self._on_clients is not None:
            try:
                self._on_clients(self._client_count)
            except Exception:
                log.exception("live link: the on_clients callback failed")
