"""The live link to 3D Slicer (snreg.workflow.live_link / live_messages) against pyigtl's own client: what each device
carries, latest wins, late joiners, clients that leave or stall, and the process's signal handlers left alone."""

import signal
import socket
import threading
import time
from types import SimpleNamespace

import numpy as np
import pyigtl
import pytest
from conftest import shown
from scipy.spatial.transform import Rotation

from snreg.errors import LiveLinkError
from snreg.geometry import apply, make_transform
from snreg.nodes import NodeSet
from snreg.workflow import live_messages as msg
from snreg.workflow.live_link import LiveLink

DEVICES = 8     # ProbeTipToTrocar, IntraopNodes, PreopNodes, IntraopLandmarks, PreopLandmarks, TrocarToRas,
#                 MissingHotSpots, Status


def frame(pose):
    """The one field of a FrameOutcome the link reads."""
    return SimpleNamespace(trocar_from_probe=pose)


def node(node_id, xyz, label="", kind="node"):
    return SimpleNamespace(id=node_id, xyz_trocar=np.asarray(xyz, dtype=float), label=label, kind=kind)


def unpack(data: bytes):
    """One packed message read back by pyigtl's parser."""
    header = pyigtl.MessageBase.parse_header(data[:pyigtl.MessageBase.IGTL_HEADER_SIZE])
    message = pyigtl.MessageBase.create_message(header["message_type"])
    message.unpack(header, data[pyigtl.MessageBase.IGTL_HEADER_SIZE:])
    return message


def stalled_socket(port: int) -> socket.socket:
    """A client that connects and never reads, with the smallest receive buffer the kernel allows."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)
    sock.connect(("127.0.0.1", port))
    return sock


@pytest.fixture
def link():
    with LiveLink(0, stall_drop_s=60.0) as served:
        yield served


def test_messages_carry_the_contract():
    pose = make_transform(Rotation.from_euler("xyz", [10, -20, 30], degrees=True).as_matrix(), [1.0, -2.0, 240.0])
    transform = unpack(msg.probe_pose(pose, 1.7e9))
    assert transform.message_type == "TRANSFORM" and transform.device_name == "ProbeTipToTrocar"
    np.testing.assert_allclose(transform.matrix, pose, atol=1e-4)          # float32 on the wire
    points = unpack(msg.point_list("IntraopNodes", ["SN1", "SN2"], [[1, 2, 3], [4, 5, 6]]))
    assert points.names == ["SN1", "SN2"] and np.allclose(points.positions, [[1, 2, 3], [4, 5, 6]])
    emptied = unpack(msg.point_list("IntraopNodes", [], np.zeros((0, 3))))     # one hidden point: Slicer drops none
    assert emptied.names == [msg.NO_POINTS_NAME] and emptied.rgba_colors[0][3] == 0 and shown(emptied)[0] == []
    preop = unpack(msg.preop_points(["A"], [[10.0, -20.0, 30.0]]))
    assert preop.device_name == "PreopNodes" and np.allclose(preop.positions, [[-10.0, 20.0, 30.0]])   # LPS -> RAS
    assert unpack(msg.status("tip at 3 mm \u2013 fine")).string == "tip at 3 mm ? fine"      # ASCII on the wire


def test_trocar_to_ras_maps_intraop_nodes_onto_the_preop_nodes_in_ras():
    preop_lps = np.array([[10.0, 20.0, 30.0], [-15.0, 5.0, 40.0], [0.0, -25.0, 10.0]])
    intraop_from_preop = make_transform(Rotation.from_euler("z", 25, degrees=True).as_matrix(), [3.0, -4.0, 200.0])
    intraop = apply(intraop_from_preop, preop_lps)
    ras_from_trocar = unpack(msg.trocar_to_ras(intraop_from_preop)).matrix
    preop_ras = np.array(unpack(msg.preop_points(["a", "b", "c"], preop_lps)).positions)
    np.testing.assert_allclose(apply(ras_from_trocar, intraop), preop_ras, atol=1e-3)


def test_a_client_gets_nodes_preop_registration_and_status_at_once(link, igtl_client):
    link.add_node(node("SN1", [1.0, 2.0, 3.0], "OBT R"))
    link.add_node(node("SN2", [4.0, 5.0, 6.0]))
    link.set_preop_nodes(NodeSet(["P1", "P2", "P3"], ["", "", ""], [[1, 2, 3], [4, 5, 6], [7, 8, 9]], frame="LPS"))
    link.set_registration(SimpleNamespace(transform=np.eye(4), method="global", rms_mm=0.5),
                          "SN1 -> P1 (with SN2); SN2 -> P1 (with SN1)")
    link.flush()
    client = igtl_client(link.port)                 # joins late: the state is sent on connect, without a new event
    assert client.wait_for(lambda c: {"IntraopNodes", "PreopNodes", "TrocarToRas", "Status"}
                           <= {m.device_name for m in c.log})
    assert shown(client.messages("IntraopNodes")[-1])[0] == ["SN1", "SN2"]
    assert np.allclose(client.messages("PreopNodes")[-1].positions[0], [-1, -2, 3])
    assert client.messages("Status")[-1].string.endswith("last: registered with global, RMS 0.50 mm: SN1 -> P1 (with "
                                                         "SN2); SN2 -> P1 (with SN1)")
    assert client.messages("ProbeTipToTrocar") == []      # no stale pose for a late joiner


def test_the_hot_spots_not_found_yet_go_as_a_point_list_in_the_trocar_frame(link, igtl_client):
    from snreg.registration.report import MissingNode

    link.set_missing([MissingNode(3, "P4", "R", np.array([12.0, -30.0, 85.0]), 6.0)])
    client = igtl_client(link.port)                 # joins late: the list is part of the state sent on connect
    assert client.wait_for(lambda c: (shown_list(c, "MissingHotSpots") or ([],))[0] == ["P4"])
    assert np.allclose(shown_list(client, "MissingHotSpots")[1], [[12.0, -30.0, 85.0]])
    link.set_missing([])                            # all found: the list empties (one hidden point)
    assert client.wait_for(lambda c: shown_list(c, "MissingHotSpots") == ([], []))


def test_a_fresh_link_sends_an_empty_missing_list_and_a_cleared_registration_is_not_given_to_joiners(link,
                                                                                                     igtl_client):
    first = igtl_client(link.port)                  # before any registration: the list, empty (a hidden point)
    assert first.wait_for(lambda c: shown_list(c, "MissingHotSpots") == ([], []))
    link.set_registration(SimpleNamespace(transform=np.eye(4), method="global", rms_mm=0.5))
    assert first.wait_for(lambda c: c.messages("TrocarToRas"))
    link.clear_registration("registration out of date")
    link.flush()
    assert first.wait_for(lambda c: c.messages("Status")[-1].string.endswith("last: registration out of date"))
    late = igtl_client(link.port)                   # joins after the clear: no stale transform passes for current
    assert late.wait_for(lambda c: {"IntraopNodes", "MissingHotSpots", "Status"} <= {m.device_name for m in c.log})
    assert late.messages("TrocarToRas") == []
    link.set_registration(SimpleNamespace(transform=np.eye(4), method="icp", rms_mm=0.7))   # a current one again
    link.flush()
    again = igtl_client(link.port)
    assert again.wait_for(lambda c: c.messages("TrocarToRas"))


def test_landmarks_have_lists_of_their_own(link, igtl_client):
    client = igtl_client(link.port)
    assert client.wait_for(lambda c: shown_list(c, "IntraopLandmarks") == ([], []))      # empty: the hidden point
    link.add_node(node("SN1", [1.0, 2.0, 3.0]))
    aorta = node("aortic bifurcation", [10.0, -20.0, 150.0], kind="landmark")
    link.add_node(aorta)
    link.set_preop_landmarks(NodeSet(["aortic bifurcation", "left common iliac bifurcation"], ["", ""],
                                     [[0.0, 85.0, 160.0], [40.0, 80.0, 95.0]], frame="LPS"))
    assert client.wait_for(lambda c: shown_list(c, "IntraopLandmarks")[0] == ["aortic bifurcation"]
                           and shown_list(c, "PreopLandmarks")[0] != [] and shown_list(c, "IntraopNodes")[0] == ["SN1"])
    assert shown_list(client, "IntraopLandmarks")[1] == [[10.0, -20.0, 150.0]]           # trocar frame, as stored
    names, positions = shown_list(client, "PreopLandmarks")
    assert names == ["aortic bifurcation", "left common iliac bifurcation"]
    assert np.allclose(positions, [[0.0, -85.0, 160.0], [-40.0, -80.0, 95.0]])            # LPS -> RAS
    assert "1 stored, 1 landmark" in client.messages("Status")[-1].string
    link.remove_node(aorta)
    assert client.wait_for(lambda c: shown_list(c, "IntraopLandmarks") == ([], []))
    assert shown_list(client, "IntraopNodes")[0] == ["SN1"]
    late = igtl_client(link.port)                    # a late joiner gets both landmark lists at once
    assert late.wait_for(lambda c: {"IntraopLandmarks", "PreopLandmarks"} <= {m.device_name for m in c.log})
    link.set_intraop_nodes([node("SN1", [1, 2, 3]), node("left common iliac bifurcation", [4, 5, 6], kind="landmark")])
    assert late.wait_for(lambda c: shown_list(c, "IntraopLandmarks")[0] == ["left common iliac bifurcation"])


def shown_list(client, device):
    """The names and positions (lists) of the newest ``device`` message a client holds; None before any."""
    messages = client.messages(device)
    if not messages:
        return None
    names, positions = shown(messages[-1])
    return names, positions.tolist()


def test_poses_stream_and_undo_empties_the_node_list(link, igtl_client):
    client = igtl_client(link.port)
    assert link.wait_for_client(10.0)
    for k in range(20):
        link.show_frame(frame(make_transform(np.eye(3), [k, 0.0, 0.0])))
        link.show_frame(frame(None))                # no fix: nothing sent
    stored = node("SN1", [1.0, 2.0, 3.0])
    link.add_node(stored)
    link.remove_node(stored)
    # the list is state, re-sent whole: the store and its undo may arrive as one message, the empty list, which
    # comes after the last pose (the list sent on connect was empty too)
    def emptied_after_the_poses(c):
        log = list(c.log)
        last_pose = max((k for k, m in enumerate(log) if m.device_name == "ProbeTipToTrocar"
                         and m.matrix[0, 3] == 19.0), default=None)
        return last_pose is not None and any(m.device_name == "IntraopNodes" and shown(m)[0] == []
                                             for m in log[last_pose:])

    assert client.wait_for(emptied_after_the_poses)
    poses = client.messages("ProbeTipToTrocar")
    assert 1 <= len(poses) <= 20 and poses[-1].matrix[0, 3] == 19.0        # latest wins: never an older one last
    assert [p.matrix[0, 3] for p in poses] == sorted(p.matrix[0, 3] for p in poses)


def test_a_burst_for_a_client_that_never_reads_leaves_one_pose_waiting(link, igtl_client):
    sock = stalled_socket(link.port)
    assert link.wait_for_client(10.0)
    for k in range(1000):
        link.show_frame(frame(make_transform(np.eye(3), [k, 0.0, 0.0])))
    link.flush(timeout_s=2.0)                       # cannot drain: the client takes nothing
    stats = link.stats()
    assert stats.clients == 1 and stats.waiting <= DEVICES      # at most one message per device waits
    assert stats.messages_replaced > 500            # the rest were replaced by newer poses, not queued
    late = igtl_client(link.port)                   # another client is served meanwhile
    assert late.wait_for(lambda c: link.clients == 2)
    link.show_frame(frame(make_transform(np.eye(3), [5000.0, 0.0, 0.0])))
    assert late.wait_for(lambda c: any(m.matrix[0, 3] == 5000.0 for m in c.messages("ProbeTipToTrocar")))
    sock.close()


def test_without_clients_poses_are_not_kept():
    with LiveLink(0) as idle:
        for k in range(1000):
            idle.show_frame(frame(np.eye(4)))
        idle.flush()
        assert idle.stats().waiting == 0 and idle.clients == 0


def test_a_client_leaving_mid_stream_leaves_the_server_serving(igtl_client):
    counts = []
    with LiveLink(0, on_clients=counts.append) as link:
        _leave_mid_stream(link, igtl_client)
    assert counts[:2] == [1, 0] and counts[-2:] == [1, 0]      # ... and 0 again once closed


def _leave_mid_stream(link, igtl_client):
    first = igtl_client(link.port)
    assert link.wait_for_client(10.0)
    link.show_frame(frame(np.eye(4)))
    assert first.wait_for(lambda c: c.messages("ProbeTipToTrocar"))
    first.stop()
    deadline = time.monotonic() + 10.0
    while link.clients and time.monotonic() < deadline:
        link.show_frame(frame(np.eye(4)))           # the stream goes on while the client disappears
        time.sleep(0.01)
    assert link.clients == 0 and link.stats().disconnected == 1
    link.add_node(node("SN1", [0.0, 0.0, 1.0]))
    second = igtl_client(link.port)
    assert second.wait_for(lambda c: c.messages("IntraopNodes") and shown(c.messages("IntraopNodes")[-1])[0] == ["SN1"])


def test_a_stalled_client_is_dropped_and_the_others_keep_their_stream(igtl_client):
    with LiveLink(0, stall_drop_s=0.5) as link:
        sock = stalled_socket(link.port)
        reader = igtl_client(link.port)
        deadline = time.monotonic() + 20.0
        while link.stats().dropped_stalled == 0 and time.monotonic() < deadline:
            link.show_frame(frame(np.eye(4)))
            time.sleep(0.005)
        assert link.stats().dropped_stalled == 1 and link.clients == 1
        link.add_node(node("SN7", [1.0, 1.0, 1.0]))
        assert reader.wait_for(lambda c: c.messages("IntraopNodes") and shown(c.messages("IntraopNodes")[-1])[0]
                               == ["SN7"])
        sock.close()


@pytest.mark.parametrize("where", ["main thread", "worker thread"])
def test_starting_and_closing_leave_the_signal_handlers_alone(where):
    def mine(*_):
        pass

    before = {signum: signal.signal(signum, mine) for signum in (signal.SIGINT, signal.SIGTERM)}
    try:
        problems = []

        def start_and_close():
            try:
                LiveLink(0).close()
            except Exception as err:          # pyigtl's server would raise ValueError off the main thread
                problems.append(err)

        if where == "main thread":
            start_and_close()
        else:
            worker = threading.Thread(target=start_and_close)
            worker.start()
            worker.join()
        assert problems == []
        assert all(signal.getsignal(signum) is mine for signum in before)
    finally:
        for signum, handler in before.items():
            signal.signal(signum, handler)


def test_a_taken_port_is_one_sentence(link):
    with pytest.raises(LiveLinkError, match="port is in use.*choose another port"):
        LiveLink(link.port)
    with pytest.raises(LiveLinkError, match="between 1 and 65535"):
        LiveLink(70000)


def test_clients_beyond_the_cap_are_told_why_and_closed_and_the_others_keep_their_stream(igtl_client):
    with LiveLink(0, max_clients=2, stall_drop_s=60.0) as link:
        reader = igtl_client(link.port)
        other = socket.create_connection(("127.0.0.1", link.port))
        deadline = time.monotonic() + 10.0
        while link.clients < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        extra = socket.create_connection(("127.0.0.1", link.port))
        extra.settimeout(10.0)
        said = b""
        while chunk := extra.recv(4096):            # one Status message, then the server closes it
            said += chunk
        assert "clients are connected already (at most 2)" in unpack(said).string
        assert link.clients == 2 and link.stats().refused == 1
        for k in range(20):
            link.show_frame(frame(make_transform(np.eye(3), [k, 0.0, 0.0])))
            assert reader.wait_for(lambda c: len(c.messages("ProbeTipToTrocar")) == k + 1)
        other.close()
        extra.close()


# Run in a process of its own whose descriptors run out: the good client connects first, then connections are
# opened until the process has none left, so the link's accept() meets EMFILE while poses go out one by one.
EMFILE_SCRIPT = r"""
import resource, socket, struct, sys, threading, time
import numpy as np
from types import SimpleNamespace
from snreg.workflow.live_link import LiveLink

resource.setrlimit(resource.RLIMIT_NOFILE, (64, resource.getrlimit(resource.RLIMIT_NOFILE)[1]))
link = LiveLink(0, max_clients=10_000, stall_drop_s=60.0)
good = socket.create_connection(("127.0.0.1", link.port))
assert link.wait_for_client(30.0)                # served before the flood: a client still waiting is not yet served
received = []

def read():
    data = b""
    while chunk := good.recv(65536):
        data += chunk
        while len(data) >= 58:
            size = 58 + struct.unpack(">Q", data[42:50])[0]
            if len(data) < size:
                break
            received.append(data[14:34].rstrip(b"\0").decode())
            data = data[size:]

threading.Thread(target=read, daemon=True).start()
flood = []
try:
    while True:
        flood.append(socket.create_connection(("127.0.0.1", link.port), timeout=1.0))
except OSError:
    pass
time.sleep(0.5)                                  # the link meets EMFILE on the connections still waiting
for k in range(40):
    link.show_frame(SimpleNamespace(trocar_from_probe=np.eye(4)))
    deadline = time.monotonic() + 10.0
    while received.count("ProbeTipToTrocar") < k + 1 and time.monotonic() < deadline:
        time.sleep(0.002)
    if received.count("ProbeTipToTrocar") < k + 1:
        break                                    # the link stopped serving: no use waiting for the rest
link.set_registration(SimpleNamespace(transform=np.eye(4), method="global", rms_mm=0.5))
deadline = time.monotonic() + 10.0
while "TrocarToRas" not in received and time.monotonic() < deadline:
    time.sleep(0.01)
stats = link.stats()
print(received.count("ProbeTipToTrocar"), received.count("TrocarToRas"), len(flood), stats.refused,
      link._thread.is_alive())
"""


def test_running_out_of_descriptors_never_stops_the_link_for_the_clients_it_serves():
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", EMFILE_SCRIPT], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    poses, registrations, flood, refused, alive = done.stdout.split()
    assert (int(poses), int(registrations), alive) == (40, 1, "True"), done.stdout
    assert int(flood) > 10 and int(refused) >= 1, done.stdout       # the descriptors did run out at the link
