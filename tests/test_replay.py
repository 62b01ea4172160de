"""Replaying a recorded session: the recorded feeds through a frame source at their pace, the IMU stream through the
serial reader, auto-store reproducing the stored nodes."""

from __future__ import annotations

import time

import numpy as np
import pytest
from conftest import VIDEO_FIXES, start_video

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration
from snreg.demo.replay import ReplayRig, replay_headless
from snreg.errors import SourceError
from snreg.session import Session, SessionError
from snreg.session.playback import RecordedFeed
from snreg.sources import SourceState

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)


@pytest.mark.slow
def test_auto_store_on_a_replay_stores_the_same_nodes(recorded_video, tmp_path):
    path, _, _ = recorded_video
    with Session.open(path) as session:
        original = session.intraop_records()
    nodes = replay_headless(path, tmp_path / "again.h5", speed=20.0, fixes_per_node=VIDEO_FIXES)
    assert len(nodes) == len(original)
    for node, before in zip(nodes, original):
        assert np.linalg.norm(node.xyz_trocar - before.xyz_trocar) < 0.5
    with Session.open(tmp_path / "again.h5") as session:          # the replay is recorded like a live session
        [segment] = session.videos()                              # from the row its encoder started at
        assert segment.frames[0] == session.stream("frames").shape[0] - segment.first_row > 0


@pytest.mark.slow
def test_a_live_replay_keeps_the_recorded_pace_and_skips_when_behind(recorded_video):
    path, _, _ = recorded_video
    clock = [0]
    feed = RecordedFeed(path, speed=2.0, clock=lambda: clock[0])
    with Session.open(path) as session:
        times = session.stream("frames")["t_host_ns"][()]
    first = feed.read()
    assert first.index == 0 and first.t_left_ns == 0
    clock[0] = (times[10] - times[0]) // 2 + 1            # the consumer was away for 10 recorded frames at 2x
    assert feed.read().index == 10
    clock[0] = 10**12                                      # long after the end: the last frame, then the end
    assert feed.read().index == len(times) - 1
    assert feed.read() is None and feed.state is SourceState.ENDED and "played all" in feed.problem


def _session_with_imu(path, n_frames=45):
    """A short session with video and a still IMU at 208 Hz over the same time."""
    with Session.create(path, case_id="imu-replay") as session:
        session.set_calibration(stereo=thesis_calibration().scaled(0.125), chain=ChainCalibration.manual())
        start_video(session, 30.0, 240, 135)
        start = time.perf_counter_ns()
        image = np.full((135, 240, 3), 90, np.uint8)
        for k in range(n_frames):
            while not session.append_frame_pair(start + k * 33_333_333, start + k * 33_333_333, k, image, image):
                time.sleep(0.005)                      # the encoder is behind: offer the pair again
        t = start + np.arange(int(n_frames / 30 * 208)) * 4_807_692
        session.append_imu(t, t - start, np.tile([0.0, 0.0, 1.0], (len(t), 1)), np.zeros((len(t), 3)))


@pytest.mark.slow
def test_the_imu_stream_replays_through_the_serial_reader_in_step_with_the_frames(tmp_path):
    path = tmp_path / "imu.h5"
    _session_with_imu(path)
    rig = ReplayRig(path, speed=1.0)
    try:
        source = rig.frame_source()
        frames = [source.read() for _ in range(20)]
        snapshot = rig.imu.snapshot()
        assert snapshot.samples > 50 and snapshot.corrupt == 0
        at = rig.imu.orientation_at(frames[-1].t_left_ns)
        assert at.gap_s < 0.05 and np.allclose(at.earth_from_imu, np.eye(3), atol=0.05)
        source.close()
    finally:
        rig.close()


@pytest.mark.slow
def test_a_session_without_video_is_refused_in_one_sentence(tmp_path):
    path = tmp_path / "bare.h5"
    with Session.create(path, case_id="bare") as session:
        session.set_calibration(stereo=thesis_calibration())
    with pytest.raises(SessionError, match="has no recorded video to replay"):
        ReplayRig(path)
    with pytest.raises(SourceError, match="has no recorded video to replay"):
        RecordedFeed(path)


@pytest.mark.slow
def test_the_app_replays_a_session_into_a_new_one(qtbot, recorded_video, tmp_path):
    from PySide6.QtCore import QSettings

    from snreg_gui.app import MainWindow
    path, _, _ = recorded_video
    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    window = MainWindow(str(path), replay=True, speed=4.0, settings=settings)
    qtbot.addWidget(window)
    try:
        assert isinstance(window.rig, ReplayRig) and window.session.path != path
        assert window.session.path.parent == path.parent and "-replay-" in window.session.path.name
        qtbot.waitUntil(lambda: window.acquisition._last_result is not None, timeout=30_000)
        assert "replay of s.h5 (4x)" in window.windowTitle()
        qtbot.waitUntil(lambda: "\nvideo: " in window.acquisition.video_health.text(), timeout=10_000)
        assert window.worker.acquisition.insertion is None         # recorded without tracking (its streams/camera)
        assert window.acquisition.insertion_line.text() == ("camera insertion not tracked: the replayed session was "
                                                            "recorded without it")
        replayed = window.session.path
    finally:
        window._end_confirmed = True
        window.shutdown()
    with Session.open(replayed) as session:                   # recorded like a live session, video and all
        assert session.stream("frames").shape[0] > 0 and len(session.videos()) == 1
