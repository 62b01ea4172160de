"""Replaying a session whose camera slid in its trocar (issue 27): the insertion is tracked in the replay when the
session tracked it live (the rule re-tracking's "auto" follows), so the replayed nodes are mapped where the camera
really was; a session recorded without tracking replays at the chain's constant, as recorded.

The recordings: the camera sliding 20 mm between two nodes (tests/surgery_frames.py), with an IMU stream a 6-axis
IMU gives at that still orientation. A fused IMU without a magnetometer starts its heading at 0 (snreg/imu/fusion.py)
while the world's IMU has a heading of about 10 degrees, so the sessions are recorded in the fused IMU's earth frame
(the world's turned by its heading about the vertical) with the trocar's orientation in that frame: the same
geometry, as a pivot calibration with that IMU would have found it. (Without an IMU stream a replay's IMU is absent,
taken as level: the identity, and the nodes come out some 300 mm away.)"""

from dataclasses import replace

import numpy as np
import pytest
from conftest import start_video
from scipy.spatial.transform import Rotation
from surgery_frames import NODE_A, NODE_B, START_MM, SlidingWorld, slide_then_rest

from snreg.chain import ChainCalibration
from snreg.demo.replay import ReplayRig, replay_headless
from snreg.geometry import make_transform
from snreg.odometry import InsertionTracker
from snreg.session import Session
from snreg.workflow.acquisition import Acquisition, ImuReading

pytestmark = pytest.mark.realtime            # the IMU stream replays at its own pace (tests/conftest.py)

WINDOW = 4
REST = 6                # pairs at each node: a replay's window may be full and still on any of the last three
IMU_LEAD_S = 2.0        # the IMU records this long before the first pair: its fusion settles on gravity meanwhile,
                        # and a reader starved for a while (a loaded machine) still stamps settled samples near them
IMU_PERIOD_NS = 4_807_692                     # 208 Hz
SPEED = 1.0             # the IMU lines at 208 Hz, as a real one sends them


def fused_frame(world: SlidingWorld) -> tuple[np.ndarray, ChainCalibration]:
    """(earth_from_imu as the fused IMU gives it (3, 3): heading 0, the world's tilt; the chain in that earth frame)."""
    earth_from_imu = world.pose(START_MM)[1]
    heading = Rotation.from_euler("z", Rotation.from_matrix(earth_from_imu).as_euler("ZYX")[0])
    chain = replace(world.chain, trocar_from_earth=world.chain.trocar_from_earth @
                    make_transform(heading.as_matrix(), np.zeros(3)))
    return heading.inv().as_matrix() @ earth_from_imu, chain


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """(tracked, untracked, earth_from_imu): the same pairs recorded with video and a still IMU stream, SN1 stored on
    node A at the start and SN2 on node B after the slide; tracked from the chain's distance, or not tracked."""
    world = SlidingWorld()
    earth_from_imu, chain = fused_frame(world)
    pairs = slide_then_rest(world, rest=REST)
    t_imu = np.arange(-round(IMU_LEAD_S * 1e9), pairs[-1].frame.t_left_ns + 100_000_000, IMU_PERIOD_NS)
    gravity = earth_from_imu.T @ [0.0, 0.0, 1.0]                # what the accelerometer reads at rest, g
    folder = tmp_path_factory.mktemp("replay-insertion")
    paths = []
    for name, tracker in (("tracked", InsertionTracker(world.calibration, chain, probe=world.probe)),
                          ("untracked", None)):
        path = folder / f"{name}.h5"
        with Session.create(path, case_id=name) as session:
            session.set_calibration(stereo=world.calibration, chain=chain)
            session.append_imu(t_imu, t_imu + 10**10, np.tile(gravity, (len(t_imu), 1)), np.zeros((len(t_imu), 3)))
            start_video(session, 30.0, *world.calibration.image_size)
            acquisition = Acquisition(world.calibration, world.probe, chain, session, fixes_per_node=WINDOW,
                                      video_fps=30.0, insertion=tracker, clock=lambda: pairs[-1].frame.t_left_ns)
            for k, pair in enumerate(pairs):
                acquisition.process(pair.frame, ImuReading(earth_from_imu))
                if k == REST - 1:
                    acquisition.store("SN1", "")
            acquisition.store("SN2", "")
            assert session.video_state().dropped == 0
        paths.append(path)
    return *paths, earth_from_imu


def node_errors(nodes) -> list[float]:
    return [float(np.linalg.norm(node.xyz_trocar - truth)) for node, truth in zip(nodes, (NODE_A, NODE_B))]


@pytest.mark.slow
def test_a_replay_tracks_the_insertion_a_session_tracked_live_and_maps_its_nodes_where_the_camera_was(recorded,
                                                                                                     tmp_path):
    tracked, _, earth_from_imu = recorded
    rig = ReplayRig(tracked)
    try:
        assert rig.moving_camera                      # so the app's switch tracks it (options.tracks_insertion)
    finally:
        rig.close()
    nodes = replay_headless(tracked, tmp_path / "again.h5", speed=SPEED, fixes_per_node=WINDOW)
    assert len(nodes) == 2
    assert [n.trocar_camera_mm for n in nodes] == pytest.approx([START_MM, START_MM + 20.0], abs=0.5)
    assert max(node_errors(nodes)) < 1.5
    for node in nodes:                                # the IMU stream through the serial reader and the fusion
        assert np.degrees(Rotation.from_matrix(node.earth_from_imu.T @ earth_from_imu).magnitude()) < 0.5
    with Session.open(tmp_path / "again.h5") as session:
        assert len(session.stream("camera")) > 0     # a replay of it tracks it live too, and so on


@pytest.mark.slow
def test_a_replay_of_a_session_recorded_without_tracking_keeps_the_chains_constant(recorded, tmp_path):
    _, untracked, _ = recorded
    rig = ReplayRig(untracked)
    try:
        assert not rig.moving_camera
    finally:
        rig.close()
    nodes = replay_headless(untracked, tmp_path / "again.h5", speed=SPEED, fixes_per_node=WINDOW)
    assert len(nodes) == 2 and all(np.isnan(n.trocar_camera_mm) for n in nodes)
    first, second = node_errors(nodes)
    assert first < 1.5 and second > 18.0              # the slide unseen, as recorded


@pytest.mark.slow
def test_the_apps_switch_tracks_a_replays_insertion_and_the_screen_says_why_not(recorded, qapp, tmp_path):
    from PySide6.QtCore import QSettings

    from snreg_gui.acquisition.options import AcquisitionOptions
    options = AcquisitionOptions(QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat))
    rigs = [ReplayRig(path) for path in recorded[:2]]
    try:
        tracked, untracked = rigs
        assert options.tracks_insertion(tracked) and not options.tracks_insertion(untracked)
        assert options.untracked_text(untracked) == ("camera insertion not tracked: the replayed session was recorded "
                                                     "without it")
        options.track_insertion.setChecked(False)
        assert not options.tracks_insertion(tracked)
        assert "(Devices > Track the camera's insertion)" in options.untracked_text(tracked)
    finally:
        for rig in rigs:
            rig.close()
