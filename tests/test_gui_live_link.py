"""The app's live link to 3D Slicer, offscreen: the Devices menu toggle serves the demo acquisition to a pyigtl
client (stored nodes, probe poses), shows the clients and address in the stream-health area, and is remembered."""

import socket
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import shown
from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QWidget

from snreg.demo.rig import DemoRig
from snreg.demo.scene import Schedule
from snreg_gui.app import MainWindow
from snreg.nodes import NodeSet
from snreg.registration.report import MissingNode
from snreg.workflow.navigation import NavigationState
from snreg_gui.common.live_link import ENABLED_KEY, PORT_KEY, LinkState, LiveLinkControl

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture
def settings(tmp_path):
    return QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)


def open_window(qtbot, tmp_path, settings, name):
    rig = DemoRig(schedule=Schedule(rest_frames=90, move_frames=3))    # 3 s rests: the live feed skips frames under load
    window = MainWindow(str(tmp_path / name), demo=True, rig=rig, fixes_per_node=20, settings=settings)
    qtbot.addWidget(window)
    window.show()
    return window


@pytest.mark.slow
def test_the_toggle_serves_stored_nodes_and_poses_to_a_client(qtbot, tmp_path, settings, igtl_client, monkeypatch):
    window = open_window(qtbot, tmp_path, settings, "demo.h5")
    try:
        port = free_port()
        asked = []
        monkeypatch.setattr(window.live_link, "ask_port", lambda current: asked.append(current) or port)
        assert not window.live_link.action.isChecked()
        window.live_link.action.trigger()                       # Devices > Live link to 3D Slicer (OpenIGTLink)...
        assert asked == [18944] and window.live_link.action.isChecked() and window.live_link.link is not None
        client = igtl_client(port)
        screen = window.acquisition
        qtbot.waitUntil(lambda: f"1 client on 127.0.0.1:{port}" in screen.link_health.text(), timeout=30_000)
        assert screen.link_health.isVisibleTo(screen)
        screen.auto_store.setChecked(True)
        qtbot.waitUntil(lambda: screen.nodes.rowCount() >= 1, timeout=60_000)
        # waitUntil, not client.wait_for: the link is fed in this (GUI) thread, so the event loop must keep running
        qtbot.waitUntil(lambda: bool(client.messages("IntraopNodes"))
                        and shown(client.messages("IntraopNodes")[-1])[0][:1] == ["SN1"], timeout=20_000)
        assert client.messages("ProbeTipToTrocar")              # the poses stream as frames are tracked
        assert client.messages("Status")
        assert settings.value(ENABLED_KEY) in (True, "true") and int(settings.value(PORT_KEY)) == port

        window.live_link.action.trigger()                       # off: closed, the line hidden, remembered off
        assert window.live_link.link is None and not screen.link_health.isVisibleTo(screen)
        assert settings.value(ENABLED_KEY) in (False, "false")
    finally:
        window.shutdown()


def test_the_link_restarts_with_the_app_on_its_port_and_a_taken_port_says_so(qtbot, settings):
    port = free_port()
    settings.setValue(ENABLED_KEY, True)
    settings.setValue(PORT_KEY, port)
    windows = []
    for _ in range(2):                      # no rig and no session: the link starts with the window all the same
        windows.append(MainWindow(settings=settings))
        qtbot.addWidget(windows[-1])
    first, second = windows
    try:
        assert first.live_link.link is not None and first.live_link.link.port == port
        assert first.live_link.action.isChecked()
        assert second.live_link.link is None and not second.live_link.action.isChecked()   # the port is taken
        assert "port is in use" in second.statusBar().currentMessage()
    finally:
        for window in windows:
            window.shutdown()


def newest_shown(client, device):
    """The names a client was last shown on ``device`` (None before any message)."""
    messages = client.messages(device)
    return shown(messages[-1])[0] if messages else None


def test_a_restart_or_reset_sends_the_hot_spots_not_found_yet_again_and_never_a_stale_registration(qtbot, settings,
                                                                                                   igtl_client):
    parent = QWidget()
    qtbot.addWidget(parent)
    sn1 = SimpleNamespace(id="SN1", xyz_trocar=np.array([1.0, 2.0, 3.0]), label="", kind="node")
    preop = NodeSet(["P1", "P2"], ["", ""], [[1, 2, 3], [4, 5, 6]], frame="LPS")
    registered = (SimpleNamespace(transform=np.eye(4), method="global", rms_mm=0.5), "SN1 -> P1")
    state = [LinkState([sn1], preop, None, registered, [MissingNode(1, "P2", "", np.array([12.0, -30.0, 85.0]), 6.0)])]
    control = LiveLinkControl(settings, parent, lambda: state[0])
    try:
        assert control.start(free_port())           # the link starts after the registration (toggled on, app restored)
        client = igtl_client(control.link.port)
        assert client.wait_for(lambda c: newest_shown(c, "MissingHotSpots") == ["P2"] and c.messages("TrocarToRas"))
        assert np.allclose(client.messages("MissingHotSpots")[-1].positions[0], [12.0, -30.0, 85.0])
        client.stop()                                # 3D Slicer restarted: it gets the list again on connect
        restarted = igtl_client(control.link.port)
        assert restarted.wait_for(lambda c: newest_shown(c, "MissingHotSpots") == ["P2"]
                                  and newest_shown(c, "IntraopNodes") == ["SN1"] and c.messages("TrocarToRas"))

        state[0] = LinkState([sn1], preop)          # a new session: its registration is not current (or none)
        control.reset_state()
        assert restarted.wait_for(lambda c: newest_shown(c, "MissingHotSpots") == []
                                  and "no current registration" in c.messages("Status")[-1].string)
        joiner = igtl_client(control.link.port)     # joins after the reset: the stale transform is not given
        assert joiner.wait_for(lambda c: newest_shown(c, "MissingHotSpots") == []
                               and newest_shown(c, "IntraopNodes") == ["SN1"])
        assert joiner.messages("TrocarToRas") == []

        control.set_registration(*registered)        # registered again, then a node stored with "register again" off
        assert joiner.wait_for(lambda c: c.messages("TrocarToRas"))
        control.follow_navigation(NavigationState(found=("P1",), stale="out of date: register again"))
        assert joiner.wait_for(lambda c: c.messages("Status")[-1].string.endswith("out of date: register again"))
        late = igtl_client(control.link.port)
        assert late.wait_for(lambda c: newest_shown(c, "IntraopNodes") == ["SN1"])
        assert late.messages("TrocarToRas") == []
    finally:
        control.stop(remember=False)


def test_a_registration_out_of_date_when_it_ends_is_not_sent_as_current(qtbot, settings, igtl_client, monkeypatch):
    from snreg_gui.registration.panel import RegistrationPanel
    port = free_port()
    settings.setValue(ENABLED_KEY, True)
    settings.setValue(PORT_KEY, port)
    window = MainWindow(settings=settings)                   # no rig, no session: the link starts with the window
    qtbot.addWidget(window)
    try:
        client = igtl_client(port)
        assert client.wait_for(lambda c: c.messages("Status"))
        done = SimpleNamespace(transform=np.eye(4), method="global", rms_mm=0.5, pairing=np.array([0]))
        window.registration.registered.emit(done)           # a node was stored while it ran: not current
        window.live_link.link.flush()
        assert client.messages("TrocarToRas") == []
        monkeypatch.setattr(RegistrationPanel, "current_result", property(lambda panel: done))
        monkeypatch.setattr(RegistrationPanel, "pairs_line", lambda panel: "SN1 -> P1")
        window.registration.registered.emit(done)           # it answers the nodes stored now: sent
        assert client.wait_for(lambda c: c.messages("TrocarToRas"))
    finally:
        window.shutdown()
