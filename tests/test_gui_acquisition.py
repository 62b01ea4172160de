"""The demo acquisition screen end to end, offscreen: rendered feeds tracked in a worker, nodes stored
durably near the rendered truth, undo, auto-store, and the tracking and stores on the worker's thread,
not the GUI's."""

import threading
import time

import numpy as np
import pytest
from PySide6.QtCore import Qt

from snreg.demo.rig import DemoRig
from snreg.demo.scene import Schedule
from snreg.imu.monitor import ImuSnapshot
from snreg.session import Session
from snreg.tracking.uncertainty import SOURCES, ellipsoid_radius_mm
from snreg.workflow.acquisition import FrameOutcome
from snreg_gui.acquisition.node_table import NODE_COLUMNS
from snreg_gui.acquisition.screen import AcquisitionScreen
from snreg_gui.acquisition.worker import FrameResult
from snreg_gui.app import MainWindow
from snreg_gui.common.node_error import ERROR_CAPTION

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)

FIXES = 20                      # a short store window keeps the test quick (thesis: 60)


@pytest.fixture
def demo_window(qtbot, tmp_path):
    rig = DemoRig(schedule=Schedule(rest_frames=90, move_frames=3))    # 3 s rests: the live feed skips frames under load
    window = MainWindow(str(tmp_path / "demo.h5"), demo=True, rig=rig, fixes_per_node=FIXES)
    qtbot.addWidget(window)
    with qtbot.waitExposed(window):
        window.show()
    yield window, rig
    window.shutdown()


def settled_on_a_node(results, scene, screen, other_than=None):
    """The last FIXES frames were tracked resting on one node (not ``other_than``), with frames to spare before it moves."""
    recent = results[-FIXES:]
    if len(recent) < FIXES or any(r.outcome.fix is None for r in recent):
        return False
    nodes = {scene.resting_node(r.outcome.index) for r in recent} | {scene.resting_node(recent[-1].outcome.index + 15)}
    return len(nodes) == 1 and nodes != {None} and nodes != {other_than} and screen.store_button.isEnabled()


def store_when_settled(qtbot, window, results, other_than=None) -> int:
    """Wait until the probe rests on a node, press Store SN, wait for the node in the table; returns the node index."""
    scene, screen = window.rig.scene, window.acquisition
    qtbot.waitUntil(lambda: settled_on_a_node(results, scene, screen, other_than), timeout=20_000)
    node_index, rows = scene.resting_node(results[-1].outcome.index), screen.nodes.rowCount()
    qtbot.mouseClick(screen.store_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == rows + 1, timeout=5_000)
    return node_index


@pytest.mark.slow
def test_store_nodes_in_demo(qtbot, demo_window):
    window, rig = demo_window
    screen = window.acquisition
    results = []
    window.worker.frame_processed.connect(results.append)
    qtbot.waitUntil(lambda: len(results) > 0, timeout=30_000)      # the scene is rendered: acquisition runs
    # the tracking and the store's durable write run on the worker's thread, never blocking the GUI's (how long the
    # GUI thread stalls is measured by 'python -m snreg_gui.bench': numbers live in benchmarks, not timed tests)
    worked_in = set()
    for signal in (window.worker.frame_processed, window.worker.node_stored):
        signal.connect(lambda _: worked_in.add(threading.get_ident()), Qt.ConnectionType.DirectConnection)
    first = store_when_settled(qtbot, window, results)
    second = store_when_settled(qtbot, window, results, other_than=first)
    assert worked_in and threading.get_ident() not in worked_in
    assert [screen.nodes.item(row, 0).text() for row in range(2)] == ["SN1", "SN2"]
    qtbot.waitUntil(lambda: set(window.error_sources) == {"SN1", "SN2"}, timeout=5_000)   # each node's error by source
    qtbot.mouseClick(screen.undo_button, Qt.MouseButton.LeftButton)          # take SN2 back, then store it again
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == 1, timeout=5_000)
    assert "undone: SN2" in screen.store_status.text() and set(window.error_sources) == {"SN1"}
    second = store_when_settled(qtbot, window, results, other_than=first)
    assert screen.nodes.item(1, 0).text() == "SN2"
    qtbot.waitUntil(lambda: "SN2" in window.error_sources, timeout=5_000)
    sources = dict(window.error_sources)
    radius = screen.nodes.item(0, NODE_COLUMNS.index(ERROR_CAPTION)).text()
    session_path = window.session.path
    window.shutdown()

    with Session.open(session_path) as session:
        nodes = session.intraop_records()
    assert [n.id for n in nodes] == ["SN1", "SN2"]
    for node, node_index in zip(nodes, (first, second)):
        truth_camera = rig.scene.truth_tip(node_index)
        truth_trocar = truth_camera + [0.0, 0.0, rig.chain.trocar_camera_mm]     # IMU still at the chain's reference
        assert np.linalg.norm(node.xyz_camera - truth_camera) < 1.5
        assert np.linalg.norm(node.xyz_trocar - truth_trocar) < 2.0
        assert node.spread_mm < 1.0 and node.n_frames == FIXES
        assert len(node.left_jpeg) > 0 and len(node.right_jpeg) > 0
        assert set(sources[node.id]) == set(SOURCES)                      # the sources add up to the stored covariance
        np.testing.assert_allclose(sum(sources[node.id].values()), node.cov_trocar_mm2, atol=1e-9)
    assert radius == f"\u00b1{ellipsoid_radius_mm(nodes[0].cov_trocar_mm2):.1f}"


@pytest.mark.slow
def test_auto_store_stores_a_node_once_the_probe_is_held_still(qtbot, demo_window):
    window, rig = demo_window
    screen = window.acquisition
    results = []
    window.worker.frame_processed.connect(results.append)
    screen.label_edit.setText("EXT L")
    screen.auto_store.setChecked(True)
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == 1, timeout=30_000)
    stored_at = results[-1].outcome.index
    node = window.session.intraop_records()[0]
    node_index = rig.scene.resting_node(stored_at)
    assert node.label == "EXT L" and node_index is not None
    assert np.linalg.norm(node.xyz_camera - rig.scene.truth_tip(node_index)) < 1.5
    assert node.spread_mm < 1.0                                     # stored only once the window was still
    # one node per rest: the probe rests on every phantom node once in the tour, and each is stored once
    qtbot.waitUntil(lambda: results[-1].outcome.index >= rig.schedule.cycle + stored_at, timeout=30_000)
    stored = window.session.intraop_records()
    tips = np.array([rig.scene.truth_tip(k) for k in range(len(rig.scene.node_poses))])
    nearest = [int(np.argmin(np.linalg.norm(tips - n.xyz_camera, axis=1))) for n in stored]
    assert sorted(nearest) == list(range(len(tips)))


@pytest.mark.slow
def test_a_store_before_enough_fixes_is_refused_in_words_and_on_record(qtbot, demo_window):
    window, _ = demo_window
    screen = window.acquisition
    assert not screen.store_button.isEnabled()                       # no frame yet: nothing to ask the worker
    qtbot.waitUntil(lambda: "collecting fixes" in screen.store_reason.text() or "ready" in screen.store_reason.text(),
                    timeout=30_000)
    screen.fixes_spin.setValue(500)      # more than the worker can have yet
    assert "collecting fixes" in screen.store_reason.text() and "of 500" in screen.store_reason.text()
    qtbot.mouseClick(screen.store_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: screen.store_status.text().startswith("Refused (button): only"), timeout=5_000)
    assert "of 500 valid fixes so far; hold the probe on the node" in screen.store_status.text()
    [event] = window.session.events("store_refused")
    assert event["trigger"] == "button" and "of 500 valid fixes" in event["reason"]


class StillImu:
    """An IMU stand-in that always reports a fresh, level sample."""

    def snapshot(self):
        return ImuSnapshot("streaming", "", 208.0, 0.0, (0.0, 0.0, 0.0), np.eye(3), 1, 0)


def frame_without_fix(reason: str) -> FrameResult:
    rgb = np.zeros((54, 96, 3), np.uint8)
    outcome = FrameOutcome(0, None, reason, None, 0, float("nan"), False, False, 5.0)
    return FrameResult(outcome, rgb, rgb, None, None, StillImu().snapshot(), 0.0, 30.0, time.perf_counter_ns())


def test_store_disabled_with_the_tracking_reason_and_stale_feed_flagged(qtbot):
    screen = AcquisitionScreen(StillImu(), fixes_per_node=5)
    qtbot.addWidget(screen)
    screen.show_result(frame_without_fix("no probe stripe found in the left image"))
    assert screen.store_reason.text() == ("not ready: collecting fixes, 0 of 5 (no valid fix: no probe stripe found "
                                          "in the left image)")
    qtbot.waitUntil(lambda: "no fix (no probe stripe found in the left image)" in screen.tip_trocar.text(), timeout=1_000)
    qtbot.waitUntil(lambda: "STALE" in screen.video_health.text(), timeout=3_000)     # no frame for over 1 s
    assert screen.store_reason.text().startswith("no frames for") and not screen.store_button.isEnabled()


@pytest.mark.slow
def test_the_surgery_demo_follows_the_camera_insertion_in_the_app(qtbot, tmp_path):
    """``snreg-gui --demo --camera surgery``: the rig's camera moves, so the worker tracks its insertion; the
    frames of a move are mapped at the insertion the camera slid to (a quarter of the thesis resolution)."""
    rig = DemoRig(scale=0.25, schedule=Schedule(rest_frames=45), camera="surgery")
    window = MainWindow(str(tmp_path / "surgery.h5"), demo=True, rig=rig, fixes_per_node=FIXES)
    qtbot.addWidget(window)
    results = []

    def settled(result) -> bool:            # through the first move, 10 frames into the next rest
        start = rig.scene.tour.rest_starts[1]             # the scene exists once a frame was processed
        return start + 10 <= result.outcome.index % rig.scene.cycle < start + rig.schedule.rest_frames

    try:
        window.worker.frame_processed.connect(results.append)
        qtbot.waitUntil(lambda: any(settled(r) for r in results), timeout=90_000)
    finally:
        window.shutdown()
    steps = [r.outcome.insertion for r in results]
    assert all(step is not None for step in steps)
    last = next(r for r in results if settled(r)).outcome      # a loaded machine may have processed frames beyond it
    truth = rig.scene.path.insertion_mm[last.index % rig.scene.cycle]
    assert last.insertion.estimate.tracked and abs(last.insertion.used_mm - truth) < 1.0
    assert abs(truth - rig.chain.trocar_camera_mm) > 10.0                 # the camera did slide
