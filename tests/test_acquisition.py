"""The acquisition core (snreg.workflow.acquisition) shared by the app and the headless demo: fixes, streams, store, undo,
auto-store, and the store guard (refusals in words and on record, confirmation near a stored node)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration, camera_to_trocar
from snreg.demo.scene import PhantomScene, Schedule
from snreg.imu.protocol import ImuSample
from snreg.probe import default_probe_model
from snreg.session import Session
from snreg.sources import StereoFrame
from snreg.workflow.acquisition import Acquisition, ImuReading, StoreError, StoreNeedsConfirmation, StoreRefused

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


class Clock:
    """Host time the test moves by hand (no sleeping)."""

    def __init__(self):
        self.ns = 10**12

    def __call__(self):
        return self.ns


@pytest.fixture
def guarded(tmp_path, scene):
    session = Session.create(tmp_path / "g.h5", case_id="t-2", stream_flush_s=0)
    clock = Clock()
    yield Acquisition(scene.renderer.calibration, default_probe_model(), ChainCalibration.manual(), session,
                      fixes_per_node=4, clock=clock), clock
    session.close()


def fill(acquisition, scene, node, imu=LEVEL, n=4):
    for index in range(n):
        outcome = acquisition.process(frame_on(scene, node, index), imu)
    return outcome


def refused_events(acquisition):
    return [(e["reason"], e["trigger"]) for e in acquisition.session.events("store_refused")]


def test_a_store_with_a_stale_imu_is_refused_in_words_and_put_on_record(guarded, scene):
    acquisition, _ = guarded
    stale = ImuReading(np.eye(3), gap_s=3.2, state="disconnected")
    outcome = fill(acquisition, scene, 0, stale)
    assert "IMU is stale" in outcome.store_check.refusal and not outcome.auto_store_due
    with pytest.raises(StoreRefused, match=r"IMU is stale: no sample within 3\.2 s of a frame \(IMU disconnected\)"):
        acquisition.store("SN1", "OBT R", trigger="F5")
    assert acquisition.session.intraop_records() == []
    [(reason, trigger)] = refused_events(acquisition)
    assert "IMU is stale" in reason and trigger == "F5"
    fill(acquisition, scene, 0)                                       # fresh readings again: stored
    assert acquisition.store("SN1", "OBT R").id == "SN1"


def test_an_absent_imu_refuses_unless_the_session_runs_without_one_by_choice(tmp_path, scene):
    absent = ImuReading(np.eye(3), gap_s=0.0, state="absent")
    for required, stored in ((True, False), (False, True)):
        with Session.create(tmp_path / f"a{required}.h5", case_id="t-3") as session:
            acquisition = Acquisition(scene.renderer.calibration, default_probe_model(), ChainCalibration.manual(),
                                      session, fixes_per_node=4, imu_required=required)
            fill(acquisition, scene, 0, absent)
            if stored:
                assert acquisition.store("SN1", "").id == "SN1"
            else:
                with pytest.raises(StoreRefused, match="there is no IMU"):
                    acquisition.store("SN1", "")
                assert len(session.events("store_refused")) == 1


def test_a_stale_fix_is_refused(guarded, scene):
    acquisition, clock = guarded
    fill(acquisition, scene, 0)
    black = np.zeros_like(scene.render(0)[0])
    clock.ns += 2_500_000_000                                          # 2.5 s with frames but no probe
    outcome = acquisition.process(StereoFrame(black, black, 0, 0, 9), LEVEL)
    assert outcome.valid_fixes == 4 and "2.5 s old" in outcome.store_check.refusal
    with pytest.raises(StoreRefused, match=r"last valid fix is 2\.5 s old \(no probe stripe.*not tracked now"):
        acquisition.store("SN1", "", trigger="button")
    assert refused_events(acquisition)[0][1] == "button"


def test_a_window_spread_over_the_limit_is_refused_and_the_limit_is_a_setting(guarded, scene):
    acquisition, _ = guarded
    acquisition.process(frame_on(scene, 0, 0), LEVEL)
    outcome = fill(acquisition, scene, 1, n=3)                         # the probe moved between nodes
    spread = outcome.window_spread_mm
    assert spread > 2.0 and not outcome.auto_store_due
    with pytest.raises(StoreRefused, match=rf"probe moved: the last 4 fixes spread {spread:.1f} mm \(limit 2\.0 mm\)"):
        acquisition.store("SN1", "", trigger="Space")
    acquisition.set_max_spread(spread + 1.0)
    assert acquisition.check_store().refusal == ""
    assert acquisition.store("SN1", "").spread_mm == pytest.approx(spread)


def test_a_store_near_a_stored_node_asks_first_naming_it(guarded, scene):
    acquisition, _ = guarded
    fill(acquisition, scene, 2)
    acquisition.store("SN1", "INT L")
    outcome = fill(acquisition, scene, 2)
    assert outcome.store_check.near.id == "SN1" and not outcome.auto_store_due
    with pytest.raises(StoreNeedsConfirmation, match=r"SN1 \(INT L\) is already stored \d\.\d mm from here") as asked:
        acquisition.store("SN2", "")
    assert asked.value.near == "SN1" and [n.id for n in acquisition.session.intraop_records()] == ["SN1"]
    assert refused_events(acquisition) == []                          # asked, not refused
    assert acquisition.store("SN2", "", confirmed=True).id == "SN2"
    [event] = acquisition.session.events("store_near_confirmed")
    assert (event["node_id"], event["near"]) == ("SN2", "SN1")


def test_a_node_keeps_its_camera_tip_orientation_and_calibration_versions(guarded, scene):
    acquisition, _ = guarded
    turned = Rotation.from_euler("ZYX", [10.0, 5.0, -3.0], degrees=True).as_matrix()
    fill(acquisition, scene, 1, ImuReading(turned))
    node = acquisition.store("SN1", "")
    np.testing.assert_allclose(node.earth_from_imu, turned, atol=1e-9)
    np.testing.assert_allclose(node.xyz_trocar, camera_to_trocar(acquisition.chain, turned, node.xyz_camera), atol=0.5)
    assert node.measured_under == (acquisition.stereo_version, acquisition.chain_version)
    assert len(node.stereo_version) == 8 and len(node.chain_version) == 8
    assert node.time_ns == frame_on(scene, 1, 3).t_left_ns          # its newest fix's grab time: a probe row's time
    with Session.open(acquisition.session.path) as reopened:            # the journal and the HDF5 rows agree
        np.testing.assert_allclose(reopened.intraop_records()[0].earth_from_imu, turned, atol=1e-9)
