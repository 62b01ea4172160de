"""The surgery demo (issue 27): the camera slides and turns between node rests over tissue fixed in the trocar frame,
the simulated IMU reports that motion in step with the rendered frames through the real serial path, and the headless
demo stores every node where it is."""

import numpy as np
import pytest

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration, camera_to_trocar
from snreg.demo.headless import run_headless
from snreg.demo.rig import DemoRig
from snreg.demo.scene import Schedule, phantom_tips
from snreg.demo.surgery_scene import REST_KEYS, SurgeryScene
from snreg.geometry import apply, invert, rotation_angle_deg
from snreg.probe import default_probe_model
from snreg.session import Session
from snreg.session.schema import CAMERA_STATES
from snreg.workflow.acquisition import ImuReading

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)

FPS = 30.0


@pytest.fixture(scope="module")
def scene():
    """The tour at a quarter of the thesis resolution (its geometry does not depend on it); nothing rendered."""
    return SurgeryScene(thesis_calibration().scaled(0.25), default_probe_model(), Schedule(rest_frames=40), fps=FPS)


def in_view_px(calibration, points_camera: np.ndarray) -> np.ndarray:
    """(N,) how far (px) inside both images each point (left camera frame) projects; negative: outside."""
    width, height = calibration.image_size
    margins = []
    in_right = points_camera @ calibration.R.T + calibration.T.ravel()
    for K, points in ((calibration.K1, points_camera), (calibration.K2, in_right)):
        uv = (points / points[:, 2:]) @ K.T
        margins.append(np.min([uv[:, 0], width - uv[:, 0], uv[:, 1], height - uv[:, 1]], axis=0))
    return np.min(margins, axis=0)


def test_the_camera_slides_and_turns_between_rests_within_its_bounds_and_steps(scene):
    poses = np.array([scene.trocar_from_camera(k) for k in range(scene.cycle + 1)])
    insertion = scene.path.insertion_mm
    start = scene.chain.trocar_camera_mm
    assert insertion.min() == pytest.approx(start - 30.0) and insertion.max() == pytest.approx(start + 30.0)
    turns = rotation_angle_deg(poses[:, :3, :3])
    assert 15.0 <= turns.max() <= 20.0
    steps_mm = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    steps_deg = rotation_angle_deg(np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3]))
    assert np.abs(np.diff(np.append(insertion, insertion[0]))).max() <= 2.5 + 1e-9
    assert steps_mm.max() <= 5.0 and steps_deg.max() <= 1.5 + 1e-9
    np.testing.assert_allclose(poses[-1], poses[0], atol=1e-9)               # the tour returns to its start
    for n, first in enumerate(scene.tour.rest_starts):                       # still while the probe rests
        rest = range(first, first + scene.schedule.rest_frames)
        assert all(scene.resting_node(k) == n for k in rest)
        np.testing.assert_allclose(poses[list(rest)], poses[[first] * len(rest)], atol=1e-12)
    assert all(scene.resting_node(k) is None for k in range(scene.schedule.rest_frames, scene.tour.rest_starts[1]))


def test_every_node_stays_in_view_but_in_the_look_around_and_the_probe_rests_on_it(scene):
    calibration, probe = scene.tissue.renderer.calibration, scene.tissue.renderer.probe
    margins = np.array([in_view_px(calibration, apply(invert(scene.trocar_from_camera(k)), scene.nodes_trocar))
                        for k in range(scene.cycle)])
    look_around = np.zeros(scene.cycle, bool)             # the move from the third rest to the fourth
    look_around[scene.tour.rest_starts[2] + scene.schedule.rest_frames:scene.tour.rest_starts[3]] = True
    assert margins[~look_around].min() > 0.05 * calibration.image_size[1]     # all four, both eyes, every other frame
    assert 15 <= (margins[look_around, 3] < 0).sum() <= 45                    # the fourth leaves the view about 1 s
    for n, first in enumerate(scene.tour.rest_starts):
        for k in (first, first + scene.schedule.rest_frames - 1):
            pose = scene.pose(k)
            tip = apply(scene.trocar_from_camera(k), pose.tip[None])[0]
            np.testing.assert_allclose(tip, scene.truth_trocar(n), atol=1e-9)
            stripes = np.array([pose.point(s + d) for s in probe.stripe_centres_mm for d in (-2.0, 2.0)])
            assert in_view_px(calibration, stripes).min() > 0
        # the tissue passes through the node: the left eye's ray through it meets the tissue there
        pose = scene.trocar_from_camera(first)
        node = apply(invert(pose), scene.truth_trocar(n)[None])[0]
        u, v = np.round((calibration.K1 @ (node / node[2]))[:2]).astype(int)
        assert scene.tissue.distance_ahead(pose)[v, u] == pytest.approx(np.linalg.norm(node), abs=1.5)
    # the nodes are where the still phantom's are (its level IMU: the camera frame shifted along the shaft)
    still = camera_to_trocar(ChainCalibration.manual(), np.eye(3), phantom_tips(probe))
    np.testing.assert_allclose(scene.nodes_trocar, still, atol=1e-9)


def test_the_imu_profile_is_the_rendered_camera_orientation_at_every_frame(scene):
    profile = scene.tour.motion_profile(scene.chain, FPS)
    times = np.arange(2 * scene.cycle) / FPS
    truth = np.array([scene.earth_from_imu(k) for k in range(2 * scene.cycle)])
    played = profile.orientation(times).as_matrix()
    assert rotation_angle_deg(np.einsum("nji,njk->nik", truth, played)).max() < 1e-5
    assert profile.orientation([-5.0])[0].approx_equal(profile.orientation([0.0])[0])     # held before the start


@pytest.mark.slow
def test_the_simulated_imu_reports_the_rendered_orientation_at_each_frame_through_held_rests():
    """The real path: the simulator process plays the tour's motion on a pty and says when it starts, the feed counts
    its frames from then, the reader and the fusion run as with hardware, and the orientation the acquisition takes
    at a frame's grab time is the one the frame was rendered at, within the AHRS's own error (measured once it has
    settled: median 0.03 deg, p95 0.1 deg; 0.2 deg in its first seconds). Issue 35: each rest is held past its end
    until released (nobody stores: the test releases it a second later), the IMU holding with the camera over its own
    channel, and both move on together; moves are watched until 40 moving frames were processed (one move on an idle
    computer, more on a loaded one)."""
    rig = DemoRig(scale=0.125, schedule=Schedule(rest_frames=60), camera="surgery", seed=4, hold_rests=True)
    errors, truth, moving, releases, first_held = [], [], [], {}, {}
    try:
        with rig.frame_source() as source:
            holds = {first + rig.schedule.rest_frames - 1 for first in rig.scene.tour.rest_starts}   # rests' last frames
            for frame in source:
                tour = rig.tour_frame(frame.index)
                reading = ImuReading.at_frame(rig.imu, frame)
                truth.append(rig.scene.earth_from_imu(tour))
                errors.append(float(rotation_angle_deg(truth[-1].T @ reading.earth_from_imu)))
                moving.append(rig.scene.resting_node(tour) is None)
                if tour % rig.scene.cycle in holds:
                    first_held.setdefault(tour, frame.index)
                    if frame.index >= first_held[tour] + 30:               # a second past the rest's end
                        releases.setdefault(tour, []).append(rig.release_rest(frame.index))   # lifts 1 s later
                if sum(moving) >= 40 and not moving[-1] or tour > 3 * rig.scene.cycle:
                    break
    finally:
        rig.close()
    errors, moving = np.array(errors), np.array(moving)
    moved = max(float(rotation_angle_deg(truth[0].T @ rotation)) for rotation in truth)
    assert releases and all(calls[0] and not any(calls[1:]) for calls in releases.values())   # each held, released once
    assert moved > 10.0 and moving.sum() >= 40
    # the median catches an orientation taken at the wrong time (a frame late at the turn's rate is ~0.7 deg on every
    # moving frame), the max a single frame's. Under load (two CPU hogs beside other work, load 10-16 on 2 cores) the
    # simulator's samples arrived in bursts up to 0.5-1.5 s late: stamped on arrival and asked for before they came,
    # they gave frames the orientation of up to a second before (largest 2.5-22 deg during a turn); timed by the device
    # clock and waited for (snreg.imu.device_clock, ImuMonitor.orientation_at), the largest was 0.13 deg in most runs
    # (at load 22-26 some still fail at 8.55 deg: the simulator's held rest out of step with the feed; docs/changelog)
    spread = (np.median(errors[moving]), np.percentile(errors, 95), errors.max())
    assert spread[0] < 0.15 and spread[1] < 0.4 and spread[2] < 2.0, spread


@pytest.mark.slow
def test_the_headless_surgery_demo_stores_every_node_where_it_is(tmp_path):
    """End to end on the app's code (a quarter of the thesis resolution, 20 fixes a node): the camera's insertion is
    tracked, each node is mapped at the insertion it was stored at and pairs with its own hot spot."""
    run = run_headless(tmp_path / "surgery.h5", seed=1, fixes_per_node=20, scale=0.25, camera="surgery")
    out = run.to_json()
    assert out["camera"] == "surgery" and out["camera_tracking"] is True
    assert out["pairing_correct"] and len(out["nodes"]) == 4 and out["rms_mm"] < 2.0
    errors = [np.linalg.norm(np.subtract(node["xyz_trocar"], node["truth_trocar"])) for node in out["nodes"]]
    # a 10-20 mm slide unseen would put them that far off; the deep node (118 mm, OBT R) carries quarter-resolution
    # stereo's depth bias, 1.98 mm before issue 35 and 2.1-2.3 mm since its rests draw fresh noise per frame (seed 1);
    # the insertion below is the fine check
    assert max(errors) < 3.0, errors
    with Session.open(run.session_path) as session:
        camera = session.stream("camera")
        insertion = {node.id: node.trocar_camera_mm for node in session.intraop_records()}
        frames = len(session.stream("frames"))
    tracked = camera["state"] == CAMERA_STATES.index("tracked")
    assert len(camera) >= 0.95 * frames and tracked.mean() > 0.95            # a row per pair, nearly all tracked
    start = ChainCalibration.manual().trocar_camera_mm
    slides = [REST_KEYS[["EXT L", "EXT R", "OBT R", "OBT L"].index(node["label"])].slide_mm for node in out["nodes"]]
    np.testing.assert_allclose([insertion[node["id"]] for node in out["nodes"]], start + np.array(slides), atol=0.5)
