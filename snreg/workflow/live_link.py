"""The live link to 3D Slicer: an OpenIGTLink server on its own thread that the acquisition feeds without waiting.

Why the sockets are handled here rather than by pyigtl's ``OpenIGTLinkServer`` (pyigtl 0.3.4, ``comm.py``): its
constructor installs SIGINT and SIGTERM handlers (and raises ValueError off the main thread, after binding the
port); it is a ``socketserver.TCPServer``, so a second client waits unserved until the first leaves; after a client
closes, its handler loops on ``recv() == b""`` until a send fails; all devices share one deque of 100 messages, and
``send_message`` waits by default until that deque is empty (forever while no client is connected); a send held up
10 ms (its socket timeout) ends the connection mid-message. pyigtl still packs every message
(:mod:`snreg.workflow.live_messages`); nothing of it runs on the caller's thread or touches signal handlers.

Threads: the feeding methods (:meth:`LiveLink.show_frame`, :meth:`~LiveLink.add_node`, ...) only put the newest
state under a lock and wake the server thread, without a socket call; they are safe from any thread. The server
thread (:mod:`snreg.workflow.live_server`) owns every socket: it accepts clients, packs what changed and writes
without blocking. Per client, only the newest message of each device waits (latest wins), so a client that stalls
holds at most one message per device and is dropped after ``stall_drop_s`` without progress; one that connects gets
the node and landmark lists, the hot spots not found yet, the current registration and the status at once; probe poses are sent only while someone listens. Stored landmarks (points of
kind ``landmark``) go to ``IntraopLandmarks``, never to ``IntraopNodes``.

>>> link = LiveLink(18944)                  # LiveLinkError when the port is taken
>>> link.wait_for_client(30.0)             # True once Slicer (or any OpenIGTLink client) is connected
>>> link.show_frame(outcome)                # per processed frame (a FrameOutcome)
>>> link.add_node(node); link.set_registration(result)    # a stored landmark: add_node too, by its kind
>>> link.close()                            # sends what is queued (up to a second), then closes
"""

from __future__ import annotations

import errno
import socket
import threading
import time

import numpy as np

from snreg.errors import LiveLinkError
from snreg.landmarks import LANDMARK, NODE
from snreg.registration.landmark_report import unchecked_note
from snreg.workflow import live_messages as msg
from snreg.workflow.live_client import LinkStats
from snreg.workflow.live_door import MAX_CLIENTS, Door
from snreg.workflow.live_server import LISTEN, STORED, LinkServer

__all__ = ["LiveLink", "LinkStats", "LiveLinkError", "STALL_DROP_S", "SEND_BUFFER_BYTES", "MAX_CLIENTS"]

STALL_DROP_S = 10.0             # a client that takes nothing for this long while messages wait is dropped
SEND_BUFFER_BYTES = 8 * 1024    # per client (Linux doubles it): bounds how stale the poses a slow reader gets can be


class LiveLink(LinkServer):
    """Serves docs/design.md, Contracts "Live link" on ``host:port`` (port 0: any free port; ``self.port`` says which).

    ``host`` is 127.0.0.1 by default, so the surgical data stays on this computer; "0.0.0.0" serves the network.
    ``on_clients(count)`` is called from the server thread whenever the number of connected clients changes. At most
    ``max_clients`` are served; one more gets a Status line saying so and is closed. Running out of file descriptors
    (``EMFILE``) never stops the link: the connection that found none is closed and accepting pauses briefly.
    """

    def __init__(self, port: int = msg.DEFAULT_PORT, *, host: str = "127.0.0.1", on_clients=None,
                 stall_drop_s: float = STALL_DROP_S, send_buffer_bytes: int = SEND_BUFFER_BYTES,
                 max_clients: int = MAX_CLIENTS):
        if not 0 <= int(port) <= 65535:
            raise LiveLinkError(f"the live link port must be between 1 and 65535, not {port}")
        try:
            self._listener = socket.create_server((host, int(port)))
        except OSError as err:
            taken = err.errno == errno.EADDRINUSE
            raise LiveLinkError(f"cannot serve OpenIGTLink on {host}:{port}: "
                                + ("the port is in use (another snreg or Slicer server?); choose another port"
                                   if taken else f"{err.strerror or err}; choose a port above 1024")) from None
        self._listener.setblocking(False)
        self.host, self.port = self._listener.getsockname()[:2]
        self._on_clients, self._stall_drop_s, self._send_buffer = on_clients, float(stall_drop_s), int(send_buffer_bytes)
        self._door = Door(self._listener, max_clients, LISTEN)          # the cap, and no end at EMFILE
        self._wake_r, self._wake_w = socket.socketpair()
        for end in (self._wake_r, self._wake_w):
            end.setblocking(False)
        self._lock = threading.Lock()
        self._pending: dict[str, object] = {}          # device -> what to pack next (latest wins); under _lock
        self._woken = False
        self._points = {device: {} for device in STORED}   # stored nodes and landmarks by id, trocar frame
        self._action = "link started"
        self._frames = self._fixes = 0
        self._last_frame = None
        self._clients: list[Client] = []               # server thread only
        self._client_count = self._waiting = 0
        self._current: dict[str, bytes] = {}           # the packed state, server thread only
        self._counts = dict(clients_seen=0, messages_sent=0, messages_replaced=0, dropped_stalled=0, disconnected=0)
        self._cpu_s = 0.0
        self._connected = threading.Event()
        self._drained = threading.Event()
        self._closing = False
        for device in (*STORED, msg.MISSING_HOT_SPOTS):   # a client always gets the lists, empty or not (a Slicer
            self._offer(device, ([], np.zeros((0, 3))))    # kept open over a restart then shows no stale hot spots)
        self._offer(msg.STATUS, True)
        self._thread = threading.Thread(target=self._serve, name="snreg-live-link", daemon=True)
        self._thread.start()

    # -- for the callers: never blocks -------------------------------------------
    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    @property
    def clients(self) -> int:
        return self._client_count

    def show_frame(self, outcome) -> None:
        """One processed frame (a :class:`~snreg.workflow.acquisition.FrameOutcome`): its probe pose, if it has a fix,
        goes to the connected clients (a newer pose replaces one not yet sent); counted for the stream health."""
        pose = getattr(outcome, "trocar_from_probe", None)
        with self._lock:
            self._frames += 1
            self._last_frame = time.monotonic()
            if pose is None:
                return
            self._fixes += 1
            if self._client_count == 0:
                return
        self._offer(msg.PROBE_POSE, (np.array(pose, dtype=float), time.time()))

    def set_intraop_nodes(self, records) -> None:
        """All stored points (objects with ``id``, ``xyz_trocar`` and ``kind``: nodes and landmarks apart), e.g. those
        of a continued session (``session.intraop_records(kind=None)``)."""
        with self._lock:
            for device in STORED:
                self._points[device] = {}
            for r in records:
                self._points[_stored_device(r)][str(r.id)] = np.array(r.xyz_trocar, dtype=float)
            counts = [len(self._points[device]) for device in STORED]
        self._offer_points(msg.INTRAOP_LANDMARKS)
        self._offer_points(msg.INTRAOP_NODES, f"{counts[0]} stored nodes and {counts[1]} landmarks loaded")

    def add_node(self, node) -> None:
        """A node or landmark just stored (an :class:`~snreg.session.IntraopNode`; its ``kind`` says which list)."""
        device = _stored_device(node)
        with self._lock:
            self._points[device][str(node.id)] = np.array(node.xyz_trocar, dtype=float)
        label = getattr(node, "label", "")
        what = f"landmark {node.id}" if device == msg.INTRAOP_LANDMARKS else str(node.id)
        self._offer_points(device, f"stored {what}" + (f" ({label})" if label else ""))

    def remove_node(self, node) -> None:
        """A node or landmark taken back (undo)."""
        device = _stored_device(node)
        with self._lock:
            self._points[device].pop(str(node.id), None)
        self._offer_points(device, f"undid {'landmark ' if device == msg.INTRAOP_LANDMARKS else ''}{node.id}")

    def set_preop_nodes(self, nodes) -> None:
        """The preop nodes (a :class:`~snreg.nodes.NodeSet` in patient LPS, mm), sent in RAS; None clears them."""
        self._offer_preop(msg.PREOP_NODES, nodes, "preop nodes")

    def set_preop_landmarks(self, landmarks) -> None:
        """The preop landmarks (a :class:`~snreg.nodes.NodeSet` in patient LPS, mm, ids = names), sent in RAS as
        ``PreopLandmarks``; None clears them."""
        self._offer_preop(msg.PREOP_LANDMARKS, landmarks, "preop landmarks")

    def set_registration(self, result, pairs: str = "") -> None:
        """A registration done (a :class:`~snreg.registration.RegistrationResult`): ``TrocarToRas`` from its transform,
        and the status says which hot spot each node came from (``pairs``:
        :func:`~snreg.registration.naming.pairs_line`) and, with landmarks the points cannot check, that a wrong one
        would not show."""
        said = f"registered with {result.method}, RMS {float(result.rms_mm):.2f} mm"
        unchecked = unchecked_note(result)
        if unchecked:
            said += f" ({unchecked})"
        self._offer(msg.TROCAR_TO_RAS, np.array(result.transform, dtype=float), f"{said}: {pairs}" if pairs else said)

    def clear_registration(self, why: str = "no current registration") -> None:
        """No registration answers the nodes now (a new session, or nodes stored since): ``TrocarToRas`` is no longer
        part of the state a joining client gets, so a stale transform is never given as current, and the status says
        ``why``. A client already connected keeps the last transform it got (OpenIGTLink cannot take one back)."""
        self._offer(msg.TROCAR_TO_RAS, None, why)

    def set_missing(self, targets) -> None:
        """The hot spots the registration left unfound (:class:`~snreg.registration.report.MissingNode`, where it maps
        them in the trocar frame; [] when none or when no registration answers the nodes stored now), sent as
        ``MissingHotSpots``, names = preop ids."""
        ids = [str(t.preop_id) for t in targets]
        xyz = np.array([t.mapped_xyz for t in targets], dtype=float).reshape(-1, 3)
        self._offer(msg.MISSING_HOT_SPOTS, (ids, xyz))     # the status keeps saying the registration it follows

    # -- waiting and closing ------------------------------------------------------------
    def wait_for_client(self, timeout_s: float | None = None) -> bool:
        """Block until a client has connected (at any time since the start); False after ``timeout_s``."""
        return self._connected.wait(timeout_s)

    def flush(self, timeout_s: float = 1.0) -> bool:
        """Block until every queued message is written to every client (False after ``timeout_s``)."""
        self._wake()
        return self._drained.wait(timeout_s)

    def stats(self) -> LinkStats:
        with self._lock:
            return LinkStats(self._client_count, self._waiting, **self._counts, refused=self._door.refused,
                             cpu_s=self._cpu_s)

    def close(self, flush_timeout_s: float = 1.0) -> None:
        """Send what is queued (waiting up to ``flush_timeout_s``), then close every socket; safe to call twice."""
        if self._closing:
            return
        if self._client_count:
            self.flush(flush_timeout_s)
        self._closing = True
        self._wake()
        self._thread.join(5.0)

    def __enter__(self) -> "LiveLink":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- internals: callers' side ------------------------------------------------------------
    def _offer_points(self, device: str, action: str | None = None) -> None:
        with self._lock:
            points = self._points[device]
            ids, xyz = list(points), np.array(list(points.values())).reshape(-1, 3)
        self._offer(device, (ids, xyz), action)

    def _offer_preop(self, device: str, nodes, what: str) -> None:
        ids = [] if nodes is None else [str(i) for i in nodes.ids]
        xyz = np.zeros((0, 3)) if nodes is None else np.array(nodes.xyz, dtype=float).reshape(-1, 3)
        self._offer(device, (ids, xyz), f"{what}: {len(ids)}")

    def _offer(self, device: str, data, action: str | None = None) -> None:
        with self._lock:
            if device in self._pending:
                self._counts["messages_replaced"] += 1
            self._pending[device] = data
            if action is not None:
                self._action = action
                self._pending[msg.STATUS] = True
            self._drained.clear()
            wake, self._woken = not self._woken, True
        if wake:
            self._wake()

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"!")
        except (BlockingIOError, OSError):
            pass                                   # a wake-up is already waiting, or the link is closed



def _stored_device(point) -> str:
    """The list a stored point goes to by its ``kind`` (objects without one are nodes)."""
    return msg.INTRAOP_LANDMARKS if getattr(point, "kind", NODE) == LANDMARK else msg.INTRAOP_NODES
