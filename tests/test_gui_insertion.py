"""The app's screens for the camera's insertion (issue 27), offscreen: the line beside the IMU angles (tracked, LOST, a
large pivot residual, not tracked and why), the store guard while the insertion is lost (the ready line, the
"Store anyway" question from F5 and Space, the override on record, auto-store never overriding), the operator's switch
(no camera stream when off), the insertion going on across a restart and starting again under a new trocar
calibration, the re-expression of a tracked node, and the review's insertion timeline and node column.

The rig renders the camera of tests/surgery_frames.py over tissue fixed in the trocar frame: sharp pairs are tracked,
blurred ones (4 px) lose the insertion while the probe stays tracked, so the guard's refusal holds as long as they last.
"""

import os
import signal

import numpy as np
import pytest
from PySide6.QtCore import QSettings, Qt
from scipy.spatial.transform import Rotation
from conftest import process_gone, shared_memory_segments
from surgery_frames import NODE_A, PROBE_AXIS, START_MM, SlidingWorld

from snreg.chain import camera_to_trocar
from snreg.demo.renderer import ProbePose, RenderOptions
from snreg.imu.monitor import ImuAt, ImuSnapshot
from snreg.odometry import START_REASON, InsertionEstimate
from snreg.session import Session, calibration_version
from snreg.session.schema import stereo_to_dict
from snreg.sources import CallableSource
from snreg.workflow.insertion import InsertionStep, insertion_text
from snreg_gui.acquisition.insertion_line import InsertionLine
from snreg_gui.acquisition.options import RECORD_VIDEO_KEY, TRACK_INSERTION_KEY
from snreg_gui.acquisition.status import BAD, QUIET, WARN
from snreg_gui.acquisition.store_prompts import DO_NOT_STORE, STORE_ANYWAY
from snreg_gui.app import MainWindow
from snreg_gui.review.panels import NODE_COLUMNS
from snreg_gui.review.screen import ReviewScreen

FIXES = 4
TURN = Rotation.from_rotvec(np.radians([0.0, 3.0, 0.0])).as_matrix()      # what the IMU reports while blurred
TIMEOUT_MS = 30_000


class TurnableImu:
    """An IMU that streams the camera's orientation, or that orientation turned by 3 degrees (``turned``)."""

    def __init__(self, earth_from_imu):
        self.earth_from_imu, self.turned = earth_from_imu, False

    def start(self):
        return self

    def stop(self):
        pass

    def take_samples(self):
        return []

    def snapshot(self):
        return ImuSnapshot("streaming", "", 208.0, 0.0, (0.0, 0.0, 0.0), self.earth_from_imu, 1, 0)

    def orientation_at(self, t_host_ns):
        return ImuAt(self.earth_from_imu @ (TURN if self.turned else np.eye(3)), 0.0, "streaming")


class SlidingRig:
    """The camera at the start insertion with the probe on node A: ``view`` "sharp" (tracked) or "blurred" (the
    insertion lost, the probe tracked, the IMU turned); pairs pre-rendered, two noise variants each."""

    simulated, description, fps, moving_camera = True, "test rig: sliding camera", 30.0, True

    def __init__(self, world, pairs):
        self.calibration, self.probe, self.chain = world.calibration, world.probe, world.chain
        self.imu = TurnableImu(world.pose(START_MM)[1])
        self.pairs, self.view = pairs, "sharp"

    def show(self, view: str) -> None:
        self.view = view
        self.imu.turned = view == "blurred"

    def frame_source(self):
        return CallableSource(lambda index: self.pairs[self.view][index % 2], self.fps, live=True, name="test feed")

    def close(self):
        pass


@pytest.fixture(scope="module")
def world():
    return SlidingWorld()


@pytest.fixture(scope="module")
def pairs(world):
    pose = world.pose(START_MM)[0]
    probe = ProbePose.make(pose[:3, :3].T @ (NODE_A - pose[:3, 3]), pose[:3, :3].T @ PROBE_AXIS)
    return {view: [world.scene.render(pose, probe, RenderOptions(noise_sigma=2.0, seed=seed, blur_sigma_px=blur))
                   for seed in (1, 2)] for view, blur in (("sharp", 0.0), ("blurred", 4.0))}


@pytest.fixture
def open_window(qtbot, tmp_path):
    windows = []

    def make(rig, **settings_values):
        settings = QSettings(str(tmp_path / f"settings{len(windows)}.ini"), QSettings.Format.IniFormat)
        for key, value in {RECORD_VIDEO_KEY: False, **settings_values}.items():     # no video: a quicker start
            settings.setValue(key, value)
        window = MainWindow(str(tmp_path / f"case{len(windows)}.h5"), fixes_per_node=FIXES, settings=settings)
        qtbot.addWidget(window)
        window.set_rig(rig)
        with qtbot.waitActive(window):                     # the Store SN keys act in the active window
            window.show()
            window.activateWindow()
        windows.append(window)
        return window
    yield make
    for window in windows:
        window.shutdown()


def press(qtbot, screen, key):
    window = screen.window()
    if not window.isActiveWindow():                       # a dialog just closed (offscreen does not give it back)
        with qtbot.waitActive(window):
            window.activateWindow()
    qtbot.keyClick(screen, key)


@pytest.mark.slow
def test_a_store_while_the_insertion_is_lost_is_refused_offered_and_overridden_on_record(qtbot, open_window, world,
                                                                                          pairs):
    rig = SlidingRig(world, pairs)
    window = open_window(rig)
    screen = window.acquisition
    line = screen.insertion_line
    qtbot.waitUntil(lambda: line.text() == f"camera {START_MM:.1f} mm, +0.0 mm since calibration, tracked",
                    timeout=TIMEOUT_MS)
    assert line.state == "tracked" and line.styleSheet() == ""
    qtbot.waitUntil(lambda: screen.store_reason.text().startswith("ready"), timeout=TIMEOUT_MS)
    rig.show("blurred")
    qtbot.waitUntil(lambda: line.text().startswith("camera LOST (the view is blurred"), timeout=TIMEOUT_MS)
    assert f": {START_MM:.1f} mm held, +0.0 mm since calibration" in line.text()
    assert line.state == "lost" and line.styleSheet() == BAD                   # stands out, as STALE does
    qtbot.waitUntil(lambda: screen.store_reason.text().startswith(
        "not ready: the camera's insertion is lost (the view is blurred"), timeout=TIMEOUT_MS)
    assert "the camera turned 3.0 degrees since it was last tracked" in screen.store_reason.text()
    assert screen.store_button.isEnabled()
    screen.auto_store.setChecked(True)                    # auto-store never overrides
    qtbot.wait(500)
    assert screen.confirm_box is None and window.session.intraop_records() == []
    screen.auto_store.setChecked(False)

    press(qtbot, screen, Qt.Key.Key_F5)
    qtbot.waitUntil(lambda: screen.confirm_box is not None, timeout=5_000)
    box = screen.confirm_box
    assert box.text().startswith("Refused (F5): the camera's insertion is lost (the view is blurred")
    assert box.text().endswith("show the tissue to the camera, or store anyway (the override is kept on record).")
    assert box.informativeText().startswith("Store anyway only if you know the camera has not slid")
    assert screen.store_status.text() == "Refused (F5): the camera's insertion is lost; store anyway or not?"
    assert box.defaultButton().text() == DO_NOT_STORE                   # Enter, or a Space meant for Store SN, is safe
    [no] = [b for b in box.buttons() if b.text() == DO_NOT_STORE]
    no.click()
    assert screen.confirm_box is None
    assert screen.store_status.text() == "Not stored: you chose not to store while the camera's insertion is lost."

    press(qtbot, screen, Qt.Key.Key_Space)
    qtbot.waitUntil(lambda: screen.confirm_box is not None, timeout=5_000)
    [anyway] = [b for b in screen.confirm_box.buttons() if b.text() == STORE_ANYWAY]
    anyway.click()
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == 1, timeout=5_000)
    assert screen.store_status.text().startswith("stored SN1 anyway, the override on record (spread ")
    [node] = window.session.intraop_records()
    assert node.trocar_camera_mm == pytest.approx(START_MM, abs=0.3)          # mapped at the insertion held
    refused = window.session.events("store_refused")
    assert [(e["trigger"], e["overridable"]) for e in refused] == [("F5", True), ("Space", True)]
    [override] = window.session.events("store_override")
    assert (override["node_id"], override["trigger"]) == ("SN1", "Space")
    assert override["reason"].startswith("the camera's insertion is lost (the view is blurred")

    rig.show("sharp")                                     # the tissue back in view: tracked again, nothing refused
    qtbot.waitUntil(lambda: line.state == "tracked" and screen.store_reason.text().startswith("ready"),
                    timeout=TIMEOUT_MS)


def test_the_insertion_goes_on_across_a_restart_and_starts_again_under_a_new_trocar_calibration(qtbot, open_window,
                                                                                                 world, pairs):
    window = open_window(SlidingRig(world, pairs))
    qtbot.waitUntil(lambda: window.acquisition.insertion_line.state == "tracked", timeout=TIMEOUT_MS)
    followed = window.worker.acquisition.insertion
    sent = followed.tracker                 # a copy went to the tracking process, which followed the pairs
    window.restart_acquisition()                           # e.g. video recording switched, or a wizard cancelled
    qtbot.waitUntil(lambda: window.worker.acquisition is not None, timeout=TIMEOUT_MS)
    assert window.worker.acquisition.insertion is followed                    # its keyframes, its last insertion
    assert followed.tracker is not sent     # handed back when the first worker stopped, and sent on from there
    stopped_at = followed.last.estimate.index
    qtbot.waitUntil(lambda: followed.last.estimate.index != stopped_at, timeout=TIMEOUT_MS)
    assert followed.last.estimate.index == stopped_at + 1 and followed.last.estimate.reason != START_REASON
    new = world.chain.with_insertion(START_MM + 12.0)
    window.session.set_calibration(chain=new)              # what the trocar wizard does, then the app applies it
    window.apply_chain(new)
    window.restart_acquisition()
    qtbot.waitUntil(lambda: window.worker.acquisition is not None, timeout=TIMEOUT_MS)
    assert window.worker.acquisition.insertion is not followed
    assert window.worker.acquisition.insertion.start_mm == START_MM + 12.0
    qtbot.waitUntil(lambda: window.acquisition.insertion_line.text().startswith(
        f"camera {START_MM + 12.0:.1f} mm, +0.0 mm since calibration"), timeout=TIMEOUT_MS)
    [started, restarted, renewed] = window.session.events("acquisition_started")
    assert started["insertion"] == f"tracked, from {START_MM:.1f} mm"
    assert restarted["insertion"].startswith("tracked, resumed at 158.")
    assert renewed["insertion"] == f"tracked, from {START_MM + 12.0:.1f} mm"


def test_switched_off_nothing_is_tracked_and_the_line_says_where_to_switch_it_on(qtbot, open_window, world, pairs):
    window = open_window(SlidingRig(world, pairs), **{TRACK_INSERTION_KEY: False})
    assert not window.options.track_insertion.isChecked()
    screen = window.acquisition
    qtbot.waitUntil(lambda: screen.store_reason.text().startswith("ready"), timeout=TIMEOUT_MS)
    assert screen.insertion_line.text() == ("camera insertion not tracked (Devices > Track the camera's insertion): "
                                            "nodes are mapped at the trocar calibration's distance")
    assert screen.insertion_line.styleSheet() == QUIET
    assert len(window.session.stream("camera")) == 0                          # no camera stream rows
    assert window.session.events("acquisition_started")[0]["insertion"] == "not tracked"
    window.options.track_insertion.setChecked(True)        # the switch restarts acquisition, tracking
    assert window.settings.value(TRACK_INSERTION_KEY, type=bool)
    assert window.statusBar().currentMessage().startswith("the camera's insertion is tracked from the video")
    qtbot.waitUntil(lambda: window.acquisition.insertion_line.state == "tracked", timeout=TIMEOUT_MS)
    qtbot.waitUntil(lambda: len(window.session.stream("camera")) > 0, timeout=TIMEOUT_MS)


def test_a_rig_whose_camera_does_not_slide_is_not_tracked_and_says_so(qtbot, open_window, world, pairs):
    rig = SlidingRig(world, pairs)
    rig.moving_camera = False
    window = open_window(rig)
    qtbot.waitUntil(lambda: window.acquisition.store_reason.text().startswith("ready"), timeout=TIMEOUT_MS)
    assert window.acquisition.insertion_line.text() == ("camera insertion not tracked: this rig's camera does not "
                                                        "slide in a trocar")
    assert window.worker.acquisition.insertion is None and len(window.session.stream("camera")) == 0


def test_a_tracked_node_is_re_expressed_with_its_slide_under_a_new_trocar_calibration(qtbot, open_window, world, pairs):
    window = open_window(SlidingRig(world, pairs), **{TRACK_INSERTION_KEY: False})
    earth = world.pose(START_MM)[1]
    camera = np.array([4.0, -3.0, 75.0])
    window.session.add_intraop_node(
        "SN1", "OBT R", camera_to_trocar(world.chain.with_insertion(START_MM + 20.0), earth, camera),
        xyz_camera=camera, earth_from_imu=earth, trocar_camera_mm=START_MM + 20.0,
        stereo_version=calibration_version(stereo_to_dict(world.calibration)),
        chain_version=calibration_version(world.chain.to_dict()))
    new = world.chain.with_insertion(160.0)
    window.session.set_calibration(chain=new)             # the trocar wizard stores it, then the app applies it
    window.apply_chain(new)
    prompt = window.calibration_prompt
    assert "SN1 was stored with the camera's insertion tracked: the slide tracked since the start is kept" in \
        prompt.informativeText()
    [reexpress] = [b for b in prompt.buttons() if b.text() == "Re-express SN1"]
    reexpress.click()
    [node] = window.session.intraop_records()
    assert node.trocar_camera_mm == pytest.approx(160.0 + 20.0)              # the new distance plus the slide
    np.testing.assert_allclose(node.xyz_trocar, camera_to_trocar(new.with_insertion(180.0), earth, camera), atol=1e-9)
    assert "re-expressed SN1" in window.statusBar().currentMessage()


def outcome_with(state: str, insertion_mm: float = 171.0, residual_mm: float = 0.05,
                 reason: str = "no tissue texture in view", imu_gap_s: float = 0.0):
    """A frame's outcome whose insertion tracker said ``state`` ("tracked" | "lost" | "" for tracking off)."""
    from snreg.workflow.acquisition import FrameOutcome
    if not state:
        return FrameOutcome(0, None, "", None, 0, np.nan, False, False, 1.0)
    tracked = state == "tracked"
    estimate = InsertionEstimate(0, state, insertion_mm if tracked else np.nan, 0.9 * tracked, 0.02,
                                 residual_mm if tracked else np.nan, "" if tracked else reason)
    step = InsertionStep(estimate, insertion_mm, None)
    return FrameOutcome(0, None, "", None, 0, np.nan, False, False, 1.0, insertion=step,
                        insertion_text=insertion_text(step, START_MM), imu_gap_s=imu_gap_s)


def test_the_insertion_line_reads_each_state_at_a_glance(qtbot):
    line = InsertionLine("camera insertion not tracked: this rig's camera does not slide in a trocar")
    qtbot.addWidget(line)
    line.show()
    line.show_outcome(outcome_with("tracked"))
    assert (line.text(), line.styleSheet()) == ("camera 171.0 mm, +13.0 mm since calibration, tracked", "")
    line.show_outcome(outcome_with("tracked", residual_mm=1.6))      # a trocar that moved, an IMU that is off
    assert line.text() == ("camera 171.0 mm, +13.0 mm since calibration, tracked\nthe camera is 1.6 mm off the pivot "
                           "model: the trocar moved or the IMU is off; check both, and calibrate the trocar again if "
                           "one moved")
    assert line.styleSheet() == WARN
    line.show_outcome(outcome_with("tracked", residual_mm=8.9, imu_gap_s=3.2))   # the IMU silent: its turns unseen
    assert line.text() == ("camera 171.0 mm, +13.0 mm since calibration, tracked\nthe camera is 8.9 mm off the pivot "
                           "model: the IMU has been silent for 3.2 s, so its turns are not seen; reconnect the IMU")
    assert line.styleSheet() == WARN
    line.show_outcome(outcome_with("lost"))
    assert line.text() == "camera LOST (no tissue texture in view): 171.0 mm held, +13.0 mm since calibration"
    assert line.styleSheet() == BAD and line.state == "lost"
    line.show_outcome(outcome_with(""))
    assert line.text() == "camera insertion not tracked: this rig's camera does not slide in a trocar"
    assert line.styleSheet() == QUIET
    line.resize(300, line.height())                                  # narrow: LOST in bold takes more lines, not cut
    line.show_outcome(outcome_with("lost", reason="the view is blurred (1.8 times less sharp than the tissue seen "
                                                  "there before)"))
    assert line.shown_lines == line.needed_lines() > 2


def record_tracked_session(path):
    """3 s of pairs at 30 Hz: tracked from 158 mm sliding to 168 mm, lost from 1.0 to 1.5 s (held at the last
    insertion tracked), tracked again; SN1 stored at 0.5 s, SN2 at 2.5 s."""
    t = np.arange(90) / 30.0
    host = np.round(1e12 + t * 1e9).astype(np.int64)
    insertion = START_MM + 10.0 * t / t[-1]
    lost = (t >= 1.0) & (t < 1.5)
    with Session.create(path, case_id="insertion-1", stream_flush_s=0) as session:
        session.append_frames(host, host, np.arange(len(t)))
        session.append_camera(host, host, np.where(lost, np.nan, insertion), np.where(lost, "lost", "tracked"),
                              np.where(lost, 0.0, 0.9), np.where(lost, np.nan, 0.05), np.where(lost, np.nan, 0.02))
        for k, (node_id, at) in enumerate((("SN1", 15), ("SN2", 75))):
            session.add_intraop_node(node_id, "", [k, 0.0, 200.0], xyz_camera=[k, 0.0, 40.0], time_ns=int(host[at]),
                                     trocar_camera_mm=float(insertion[at]))
    return t, insertion, lost


def test_the_review_shows_the_insertion_over_time_with_the_lost_stretch_and_the_stores(qtbot, tmp_path):
    t, insertion, lost = record_tracked_session(tmp_path / "tracked.h5")
    screen = ReviewScreen()
    qtbot.addWidget(screen)
    screen.resize(1400, 900)
    screen.show()
    with qtbot.waitSignal(screen.loaded, timeout=TIMEOUT_MS):
        screen.load(tmp_path / "tracked.h5")
    plots = screen.timelines
    x, y = plots.insertion_curve.getOriginalDataset()
    np.testing.assert_allclose(x, t - t[0], atol=1e-6)
    assert np.isnan(y[lost]).all() and np.allclose(y[~lost], insertion[~lost])      # lost: a break
    x, y = plots.lost_curve.getOriginalDataset()
    last_tracked = insertion[np.flatnonzero(lost)[0] - 1]
    np.testing.assert_allclose(x, [1.0, 1.5], atol=1e-6)                # the red bar: from the first lost pair on
    np.testing.assert_allclose(y, [last_tracked] * 2)                     # at the insertion those pairs were mapped at
    x, y = plots.node_insertions.getData()
    np.testing.assert_allclose(x, [0.5, 2.5], atol=1e-6)
    np.testing.assert_allclose(y, insertion[[15, 75]], atol=1e-4)
    assert set(plots.node_markers) == {"SN1", "SN2"} and len(plots.node_markers["SN1"]) == len(plots.plots)
    assert plots.untracked_note.toPlainText() == ""
    column = NODE_COLUMNS.index("insertion (mm)")
    assert [screen.node_table.item(r, column).text() for r in range(2)] == [f"{insertion[15]:.1f}",
                                                                             f"{insertion[75]:.1f}"]
    assert "insertion tracked on 75 pairs, lost on 15" in screen.header.text()

    with Session.create(tmp_path / "still.h5", case_id="still-1", stream_flush_s=0) as session:
        session.append_frames([10**12, 10**12 + 33_000_000], [0, 0], [0, 1])
        session.add_intraop_node("SN1", "", [0.0, 0.0, 200.0], time_ns=10**12)
    with qtbot.waitSignal(screen.loaded, timeout=TIMEOUT_MS):
        screen.load(tmp_path / "still.h5")
    assert plots.untracked_note.toPlainText() == "not tracked in this session: the chain's distance throughout"
    x, _ = plots.insertion_curve.getOriginalDataset()
    assert x is None or len(x) == 0
    assert screen.node_table.item(0, column).text() == "" and "insertion not tracked" in screen.header.text()


def test_a_killed_tracking_process_is_restarted_and_said_and_a_stopped_worker_leaves_no_process_nor_shared_memory(
        qtbot, open_window, world, pairs, created_segments):
    window = open_window(SlidingRig(world, pairs))
    screen = window.acquisition
    qtbot.waitUntil(lambda: screen.store_reason.text().startswith("ready"), timeout=TIMEOUT_MS)
    press(qtbot, screen, Qt.Key.Key_F5)
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == 1, timeout=TIMEOUT_MS)
    killed = window.worker.acquisition.tracking_pid
    os.kill(killed, signal.SIGKILL)
    qtbot.waitUntil(lambda: screen.store_status.text() == "Tracking: the tracking process ended (killed by signal 9); "
                    "restarted; the camera's insertion is no longer tracked.", timeout=TIMEOUT_MS)
    qtbot.waitUntil(lambda: screen.insertion_line.text().startswith("camera LOST (no longer tracked since the "
                                                                    "tracking process ended)"), timeout=TIMEOUT_MS)
    acquisition = window.worker.acquisition             # the probe tracked in the new process
    qtbot.waitUntil(lambda: acquisition.tracking_answering and acquisition.tracking_pid != killed, timeout=TIMEOUT_MS)
    fixes = len(window.session.stream("probe"))
    qtbot.waitUntil(lambda: len(window.session.stream("probe")) > fixes, timeout=TIMEOUT_MS)
    assert [n.id for n in window.session.intraop_records()] == ["SN1"]
    assert len(window.session.events("tracking_process_stopped")) == 1
    window.restart_acquisition()                        # a new worker, a new tracking process
    qtbot.waitUntil(lambda: window.worker.acquisition is not None, timeout=TIMEOUT_MS)
    pid = window.worker.acquisition.tracking_pid
    assert pid is not None and not process_gone(pid)
    window.shutdown()
    assert process_gone(pid) and created_segments and not created_segments & shared_memory_segments()
