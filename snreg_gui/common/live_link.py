"""The app's live link to 3D Slicer: the Devices menu toggle with its port, and feeding the link from the GUI thread.

Why a class of its own: the window only wires signals to it. The link (:class:`snreg.workflow.live_link.LiveLink`)
serves from its own thread and its feeding methods never block, so they are called right here, in the GUI thread,
from the acquisition worker's queued signals and the registration panel's results; its client count comes back
through a Qt signal. The toggle and the port are remembered (QSettings) and the link restarts with the app.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from PySide6.QtCore import QObject, QSettings, Signal
from PySide6.QtGui import QAction
from PySide6.QtWidgets import QInputDialog, QWidget

from snreg.errors import LiveLinkError
from snreg.workflow.live_link import LiveLink
from snreg.workflow.live_messages import DEFAULT_PORT

ENABLED_KEY, PORT_KEY = "live_link/enabled", "live_link/port"


@dataclass(frozen=True)
class LinkState:
    """What a live-link client sees first, whenever the link starts or the session changes: the stored nodes and
    landmarks (records with ``id``, ``xyz_trocar``, ``kind``), the preop nodes and landmarks (patient LPS NodeSets or
    None), the registration that answers the nodes stored now with its pairs line (None when there is none or the one
    shown is out of date: it must not reach Slicer as current), and the hot spots it left unfound (MissingNode list)."""

    records: list = field(default_factory=list)
    preop: object = None
    preop_landmarks: object = None
    registration: tuple | None = None
    missing: list = field(default_factory=list)


class LiveLinkControl(QObject):
    """Owns the link while it is on. ``state_changed(str)``: one line for the stream-health area ("" when off);
    ``failed(str)``: why it could not start. ``current_state()`` gives (stored nodes and landmarks, preop NodeSet, preop
    landmarks NodeSet or None, (registration result, its pairs line) or None) for a client's first look, whenever the
    link starts or the session changes."""

    state_changed = Signal(str)
    failed = Signal(str)
    _clients_changed = Signal(int)              # from the link's thread, queued to this object's

    def __init__(self, settings: QSettings, parent: QWidget, current_state: Callable[[], LinkState]):
        super().__init__(parent)
        self._settings, self._parent, self._current_state = settings, parent, current_state
        self.link: LiveLink | None = None
        self.action = QAction("Live link to 3D Slicer (OpenIGTLink)...", self)
        self.action.setCheckable(True)
        self.action.setToolTip("serve the probe, the stored and preop nodes and the registration to 3D Slicer "
                               "(OpenIGTLinkIF, as a client of this computer's port)")
        self.action.toggled.connect(self._toggled)
        self._clients_changed.connect(self._show_clients)

    @property
    def state_text(self) -> str:
        return self._describe(self.link.clients) if self.link is not None else ""

    def restore(self) -> None:
        """Start the link if it was on when the app last closed (on the remembered port, without asking)."""
        if _bool(self._settings.value(ENABLED_KEY, False)):
            self.start(self._remembered_port())

    def ask_port(self, current: int) -> int | None:
        """The port to serve on, asked when the link is switched on; None when cancelled."""
        port, ok = QInputDialog.getInt(self._parent, "Live link to 3D Slicer", "OpenIGTLink port (Slicer connects to "
                                       "it as a client):", current, 1, 65535)
        return port if ok else None

    def start(self, port: int) -> bool:
        """Serve on ``port`` with the current nodes, preop nodes and registration; False (and ``failed``) if not."""
        self.stop(remember=False)
        try:
            self.link = LiveLink(port, on_clients=self._clients_changed.emit)
        except LiveLinkError as err:
            self.failed.emit(f"Live link not started: {err}.")
            self._set_checked(False)
            return False
        self._settings.setValue(ENABLED_KEY, True)
        self._settings.setValue(PORT_KEY, port)
        self.reset_state()
        self._set_checked(True)
        self.state_changed.emit(self.state_text)
        return True

    def stop(self, remember: bool = True) -> None:
        """Close the link; ``remember``: the app starts without it next time."""
        if self.link is not None:
            self.link.close()
            self.link = None
            self.state_changed.emit("")
        if remember:
            self._settings.setValue(ENABLED_KEY, False)
        self._set_checked(False)

    def reset_state(self) -> None:
        """Send the whole current state again (the link started, or the session changed): the nodes, the registration
        only while it answers them (else the one sent before stops being given as current), and the hot spots it
        left unfound, so a Slicer that connects after a restart of either side finds them all."""
        if self.link is None:
            return
        state = self._current_state()
        self.link.set_intraop_nodes(state.records)
        self.link.set_preop_nodes(state.preop)
        self.link.set_preop_landmarks(state.preop_landmarks)
        if state.registration is not None:
            self.link.set_registration(*state.registration)
        else:
            self.link.clear_registration()
        self.link.set_missing(state.missing)

    # -- feeding, in the GUI thread (each call returns at once) ---------------------------
    def show_result(self, result) -> None:
        """A processed frame from the acquisition worker (a FrameResult)."""
        if self.link is not None:
            self.link.show_frame(result.outcome)

    def add_node(self, node) -> None:
        if self.link is not None:
            self.link.add_node(node)

    def remove_node(self, node) -> None:
        if self.link is not None:
            self.link.remove_node(node)

    def set_preop_nodes(self, nodes) -> None:
        if self.link is not None:
            self.link.set_preop_nodes(nodes)

    def set_preop_landmarks(self, landmarks) -> None:
        """The preop landmarks (patient LPS, ids = names; None: none), sent as ``PreopLandmarks``."""
        if self.link is not None:
            self.link.set_preop_landmarks(landmarks)

    def set_registration(self, result, pairs: str = "") -> None:
        if self.link is not None:
            self.link.set_registration(result, pairs)

    def follow_navigation(self, state) -> None:
        """The registration panel's :class:`~snreg.workflow.navigation.NavigationState`: once it says the result no
        longer answers the nodes stored now (``stale``, e.g. a node stored with "register again" off, or a run under
        way), the link stops giving that registration to clients that join, and says why."""
        if self.link is not None and state.stale:
            self.link.clear_registration(state.stale)

    def set_missing(self, targets) -> None:
        """The hot spots not found yet (MissingNode list, trocar frame), sent as ``MissingHotSpots``."""
        if self.link is not None:
            self.link.set_missing(targets)

    # -- internals ----------------------------------------------------------------------------
    def _toggled(self, checked: bool) -> None:
        if checked == (self.link is not None):
            return
        if not checked:
            self.stop()
            return
        port = self.ask_port(self._remembered_port())
        if port is None:
            self._set_checked(False)
            return
        self.start(port)

    def _remembered_port(self) -> int:
        try:
            return int(self._settings.value(PORT_KEY, DEFAULT_PORT))
        except (TypeError, ValueError):
            return DEFAULT_PORT

    def _set_checked(self, checked: bool) -> None:
        self.action.blockSignals(True)
        self.action.setChecked(checked)
        self.action.blockSignals(False)

    def _show_clients(self, count: int) -> None:
        if self.link is not None:
            self.state_changed.emit(self._describe(count))

    def _describe(self, count: int) -> str:
        clients = "waiting for a client" if count == 0 else f"{count} client{'s' * (count != 1)}"
        return f"Slicer link: {clients} on {self.link.address}"


def _bool(value) -> bool:
    """QSettings gives back "true"/"false" from INI files."""
    return value is True or str(value).lower() == "true"
