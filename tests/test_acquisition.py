"""The acquisition core (snreg.workflow.acquisition) shared by the app and the headless demo: fixes, streams, store, undo, auto-store."""

import numpy as np
import pytest

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration
from snreg.demo.scene import PhantomScene, Schedule
from snreg.imu.protocol import ImuSample
from snreg.probe import default_probe_model
from snreg.session import Session
from snreg.sources import StereoFrame
from snreg.workflow.acquisition import Acquisition, ImuReading, StoreError

LEVEL = ImuReading(np.eye(3))


@pytest.fixture(scope="module")
def scene():
    return PhantomScene(thesis_calibration().scaled(0.5), default_probe_model(), Schedule(rest_frames=10, move_frames=1,
                                                                                        noise_variants=2))


def frame_on(scene, node, index):
    """A pair with the probe resting on ``node`` (frame ``index`` of the run)."""
    left, right = scene.render(node * (scene.schedule.rest_frames + scene.schedule.move_frames) + index % 2)
    return StereoFrame(left, right, 1_000_000 * index, 1_000_000 * index + 2000, index)


@pytest.fixture
def acquisition(tmp_path, scene):
    session = Session.create(tmp_path / "s.h5", case_id="t-1", stream_flush_s=0)
    yield Acquisition(scene.renderer.calibration, default_probe_model(), ChainCalibration.manual(), session,
                      fixes_per_node=4)
    session.close()


def test_fixes_go_to_the_trocar_frame_and_the_streams(acquisition, scene):
    chain = acquisition.chain
    samples = [ImuSample(5, 7, [0.0, 0.0, 1.0], [0.0, 0.0, 0.0])]
    outcome = acquisition.process(frame_on(scene, 0, 0), ImuReading(np.eye(3), samples))
    assert outcome.fix is not None and outcome.reason == ""
    np.testing.assert_allclose(outcome.fix.tip, scene.truth_tip(0), atol=1.5)
    # IMU level: the trocar frame is the camera frame moved back along the shaft
    np.testing.assert_allclose(outcome.tip_trocar, outcome.fix.tip + [0, 0, chain.trocar_camera_mm], atol=1e-6)
    assert outcome.valid_fixes == 1 and np.isnan(outcome.window_spread_mm) and not outcome.still
    pose = outcome.trocar_from_probe                     # the probe pose the live link streams: tip and axis
    np.testing.assert_allclose(pose[:3, 3], outcome.tip_trocar, atol=1e-9)
    np.testing.assert_allclose(pose[:3, 2], outcome.fix.axis, atol=1e-9)
    session = acquisition.session
    assert list(session.stream("frames")["t_device_ns"]) == [2000]
    assert session.stream("probe").shape == (1,) and list(session.stream("imu")["t_device_ns"]) == [7000]


def test_a_frame_without_the_probe_gives_the_reason_and_no_fix(acquisition):
    black = np.zeros((540, 960, 3), np.uint8)
    outcome = acquisition.process(StereoFrame(black, black, 0, 0, 0), LEVEL)
    assert outcome.fix is None and "no probe stripe" in outcome.reason and outcome.valid_fixes == 0
    assert outcome.trocar_from_probe is None
    assert acquisition.session.stream("probe").shape == (0,)


def test_store_needs_a_full_window_then_stores_the_median(acquisition, scene):
    with pytest.raises(StoreError, match="0 of 4 valid fixes"):
        acquisition.store("SN1", "OBT R")
    for index in range(4):
        outcome = acquisition.process(frame_on(scene, 1, index), LEVEL)
    assert outcome.valid_fixes == 4 and outcome.still and outcome.window_spread_mm < 1.0
    assert outcome.auto_store_due
    node = acquisition.store("SN1", "OBT R", counts=812.0)
    assert np.linalg.norm(node.xyz_camera - scene.truth_tip(1)) < 1.5
    assert node.n_frames == 4 and node.counts == 812.0
    assert not acquisition.process(frame_on(scene, 1, 4), LEVEL).auto_store_due      # already stored here


def test_undo_takes_back_the_last_node_stored(acquisition, scene):
    with pytest.raises(StoreError, match="no stored node"):
        acquisition.undo()
    for node, node_id in ((0, "SN1"), (2, "SN2")):
        for index in range(4):
            acquisition.process(frame_on(scene, node, index), LEVEL)
        acquisition.store(node_id, "")
    assert acquisition.undo().id == "SN2"
    assert acquisition.session.intraop_nodes().ids == ["SN1"]
    assert acquisition.session.next_node_id() == "SN2"


def test_a_shorter_window_keeps_the_latest_fixes(acquisition, scene):
    for index in range(4):
        acquisition.process(frame_on(scene, 0, index), LEVEL)
    acquisition.set_fixes_per_node(2)
    assert acquisition.process(frame_on(scene, 0, 4), LEVEL).valid_fixes == 2
