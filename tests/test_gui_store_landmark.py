"""Store landmark on the acquisition screen, offscreen (issue 29): the name picked from the preop landmarks first,
stored through the worker as a landmark (never a node), refused in words while the probe moves, the question before
replacing a landmark of the same name, undo, and the live link's landmark lists."""

import numpy as np
import pytest
from conftest import shown
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QMessageBox

from snreg.landmarks import LANDMARK, LANDMARKS
from snreg.nodes import NodeSet, write_nodes
from snreg_gui.acquisition.node_table import NODE_COLUMNS
from test_gui_live_link import free_port
from test_gui_store_guard import FakeImu, FakeRig, on_node, open_window, scene  # noqa: F401 - fixtures

MOVING = lambda index: on_node((index // 2) % 2)(index)      # noqa: E731 - the probe between two nodes every 2 frames
TIMEOUT_MS = 20_000


def click(qtbot, screen):
    qtbot.mouseClick(screen.landmark_picker.button, Qt.MouseButton.LeftButton)


@pytest.mark.slow
def test_the_name_list_offers_the_preop_landmarks_first_then_the_vocabulary(qtbot, open_window, scene, tmp_path):
    window = open_window(FakeRig(scene, on_node(0), FakeImu()))
    picker = window.acquisition.landmark_picker
    assert picker.offered() == list(LANDMARKS) and picker.combo.isEditable()
    marks = NodeSet(["left internal iliac origin", "sacral promontory"], ["", ""], np.eye(3)[:2] * 50)
    write_nodes(NodeSet.from_xyz(np.eye(3) * 40 + 5, ["", "", ""], prefix="P"), tmp_path / "preop.csv", landmarks=marks)
    window.registration.load_preop(tmp_path / "preop.csv")
    qtbot.waitUntil(lambda: picker.offered()[:2] == ["left internal iliac origin", "sacral promontory"],
                    timeout=TIMEOUT_MS)
    assert picker.offered()[2:] == [n for n in LANDMARKS if n != "left internal iliac origin"]
    assert picker.name() == "left internal iliac origin"


@pytest.mark.slow
def test_a_landmark_file_read_in_the_preop_box_reaches_the_name_list_and_the_live_link(qtbot, open_window, scene,
                                                                                      tmp_path, monkeypatch):
    window = open_window(FakeRig(scene, on_node(0), FakeImu()))
    sent = []
    monkeypatch.setattr(window.live_link, "set_preop_landmarks", sent.append)
    path = tmp_path / "ct.csv"
    path.write_text("id,label,x,y,z,kind\nsacral promontory,,0,100,60,landmark\n")
    window.registration.preop_box.load_landmarks(path)
    qtbot.waitUntil(lambda: window.acquisition.landmark_picker.offered()[0] == "sacral promontory", timeout=TIMEOUT_MS)
    assert sent and sent[-1].ids == ["sacral promontory"]


@pytest.mark.slow
def test_store_landmark_stores_a_landmark_apart_asks_before_replacing_and_undoes(qtbot, open_window, scene):
    window = open_window(FakeRig(scene, on_node(1), FakeImu()))
    screen = window.acquisition
    qtbot.waitUntil(lambda: screen.store_reason.text().startswith("ready"), timeout=TIMEOUT_MS)
    screen.landmark_picker.combo.setEditText("Aortic  Bifurcation")          # the vocabulary's spelling is kept
    click(qtbot, screen)
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == 1, timeout=5_000)
    assert screen.store_status.text().startswith("stored landmark 'aortic bifurcation' (spread ")
    assert screen.nodes.item(0, 0).text() == "aortic bifurcation"
    assert screen.nodes.item(0, NODE_COLUMNS.index("label")).text() == "landmark"
    [record] = window.session.intraop_records(kind=None)
    assert record.kind == LANDMARK and record.id == "aortic bifurcation"
    assert len(window.session.intraop_nodes()) == 0                          # never counted as a node
    click(qtbot, screen)                                                      # the same name again: asked first
    qtbot.waitUntil(lambda: screen.confirm_box is not None, timeout=5_000)
    assert screen.confirm_box.windowTitle() == "Store landmark: replace the one stored?"
    assert screen.confirm_box.text().startswith("The landmark 'aortic bifurcation' is already stored")
    screen.store_status.setText("")
    screen.confirm_box.done(QMessageBox.StandardButton.Yes)
    qtbot.waitUntil(lambda: "stored landmark" in screen.store_status.text(), timeout=5_000)     # the new one shown
    assert len(window.session.events("landmark_replaced")) == 1
    assert screen.nodes.rowCount() == 1 and len(window.session.intraop_records(kind=None)) == 1
    qtbot.mouseClick(screen.undo_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == 0, timeout=5_000)
    assert window.session.intraop_records(kind=None) == []


@pytest.mark.slow
def test_store_landmark_is_refused_in_words_while_the_probe_moves_and_without_a_name(qtbot, open_window, scene):
    window = open_window(FakeRig(scene, MOVING, FakeImu()))
    screen = window.acquisition
    qtbot.waitUntil(lambda: "the probe moved" in screen.store_reason.text(), timeout=TIMEOUT_MS)
    screen.landmark_picker.combo.setEditText("aortic bifurcation")
    click(qtbot, screen)
    qtbot.waitUntil(lambda: screen.store_status.text().startswith("Refused (button): the probe moved"), timeout=5_000)
    [event] = window.session.events("store_refused")
    assert event["landmark"] and event["node_id"] == "aortic bifurcation"
    screen.landmark_picker.combo.setEditText("SN2")                          # a node id is no landmark name
    qtbot.waitUntil(lambda: screen.landmark_picker.button.isEnabled(), timeout=5_000)
    click(qtbot, screen)
    qtbot.waitUntil(lambda: screen.store_status.text().startswith("Not stored: 'SN2' looks like a node id"),
                    timeout=5_000)
    assert window.session.intraop_records(kind=None) == []


@pytest.mark.slow
def test_the_live_link_receives_the_stored_and_the_preop_landmarks(qtbot, open_window, scene, tmp_path, igtl_client,
                                                                   monkeypatch):
    window = open_window(FakeRig(scene, on_node(0), FakeImu()))
    screen = window.acquisition
    qtbot.waitUntil(lambda: screen.store_reason.text().startswith("ready"), timeout=TIMEOUT_MS)
    screen.landmark_picker.combo.setEditText("aortic bifurcation")
    click(qtbot, screen)
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == 1, timeout=5_000)
    port = free_port()                                          # switched on after the store: the first look has it
    monkeypatch.setattr(window.live_link, "ask_port", lambda current: port)
    window.live_link.action.trigger()
    client = igtl_client(port)
    qtbot.waitUntil(lambda: bool(client.messages("IntraopLandmarks"))
                    and shown(client.messages("IntraopLandmarks")[-1])[0] == ["aortic bifurcation"], timeout=20_000)
    assert shown(client.messages("IntraopNodes")[-1])[0] == []
    marks = NodeSet(["top of the pubic symphysis"], [""], [[1.0, 2.0, 3.0]])
    write_nodes(NodeSet.from_xyz(np.eye(3) * 40 + 5, ["", "", ""], prefix="P"), tmp_path / "preop.csv", landmarks=marks)
    window.registration.load_preop(tmp_path / "preop.csv")
    qtbot.waitUntil(lambda: bool(client.messages("PreopLandmarks"))
                    and shown(client.messages("PreopLandmarks")[-1])[0] == ["top of the pubic symphysis"],
                    timeout=20_000)
    names, xyz = shown(client.messages("PreopLandmarks")[-1])
    np.testing.assert_allclose(xyz, [[-1.0, -2.0, 3.0]], atol=1e-4)         # LPS to RAS
    window.live_link.action.trigger()
