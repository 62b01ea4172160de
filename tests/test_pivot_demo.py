"""The simulated pivot recording: poses pivot about the trocar, the IMU follows the frame read, the chain is true."""

import numpy as np
import pytest

from snreg.calibration.checkerboard import Board, find_corners
from snreg.calibration.pivot import board_from_camera_pose, imu_camera_rotation, pivot_calibration
from snreg.calibration.trocar import arc_distance
from snreg.camera import thesis_calibration
from snreg.chain import trocar_from_camera
from snreg.demo.pivot_scene import DEFAULT_IMU_FROM_CAMERA, PivotScene
from snreg.geometry import invert, rotation_distance_deg

BOARD = Board(10, 7, 10.0)
CALIBRATION = thesis_calibration().scaled(0.5)


def true_recording(scene):
    frames = range(scene.frames_per_cycle)
    return (np.array([scene.board_from_camera(k) for k in frames]), np.array([scene.earth_from_imu(k) for k in frames]))


def test_the_camera_pivots_about_the_trocar_at_the_true_distance():
    scene = PivotScene(CALIBRATION, BOARD, frames_per_cycle=36, trocar_camera_mm=150.0)
    poses, _ = true_recording(scene)
    result = pivot_calibration(poses)
    assert np.allclose(result.pivot_camera_mm, [0.0, 0.0, -150.0], atol=1e-6)
    assert result.verdict == "good" and abs(result.tilt_range_deg - 20.0) < 0.1   # 10 degrees each side
    assert scene.true_chain.trocar_camera_mm == pytest.approx(150.0)
    assert scene.true_chain.imu_trocar_mm == 460.0


def test_the_imu_turns_with_the_camera_through_the_mount_rotation():
    scene = PivotScene(CALIBRATION, BOARD, frames_per_cycle=36)
    poses, imu = true_recording(scene)
    hand_eye = imu_camera_rotation(imu, poses)
    assert rotation_distance_deg(hand_eye.imu_from_camera, DEFAULT_IMU_FROM_CAMERA) < 1e-6
    assert np.allclose(scene.true_chain.imu_from_camera[:3, :3], DEFAULT_IMU_FROM_CAMERA)


def test_the_true_chain_reproduces_the_camera_motion():
    scene = PivotScene(CALIBRATION, BOARD, frames_per_cycle=12)
    for i, j in [(0, 3), (2, 9), (5, 11)]:
        by_chain = invert(trocar_from_camera(scene.true_chain, scene.earth_from_imu(i))) @ \
            trocar_from_camera(scene.true_chain, scene.earth_from_imu(j))
        assert np.allclose(by_chain, invert(scene.trocar_from_camera(i)) @ scene.trocar_from_camera(j), atol=1e-9)


def test_every_step_is_a_swing_so_eq_14_nearly_holds_on_the_true_motion():
    """The ellipse turns a little about the shaft too; the arc method's bias on it bounds the GUI test's tolerance."""
    scene = PivotScene(CALIBRATION, BOARD, frames_per_cycle=36)
    poses, imu = true_recording(scene)
    estimate = arc_distance(poses[:, :3, 3], imu)
    assert estimate.n_used == 35 and abs(estimate.distance_mm - 158.0) < 0.5


def test_the_imu_shows_the_frame_read_last_and_frames_repeat_each_cycle():
    scene = PivotScene(CALIBRATION, BOARD, frames_per_cycle=8, seed=3)
    source = scene.frame_source()
    frames = []
    for k in range(11):
        frames.append(source.read())
        assert np.array_equal(scene.imu.snapshot().earth_from_imu, scene.earth_from_imu(k))
    assert frames[9].left is frames[1].left and frames[10].index == 10
    pose = board_from_camera_pose(find_corners(frames[2].left, BOARD), BOARD, CALIBRATION.K1, CALIBRATION.D1)
    assert np.linalg.norm(pose[:3, 3] - scene.board_from_camera(2)[:3, 3]) < 1.0
    assert rotation_distance_deg(pose, scene.board_from_camera(2)) < 0.2
    source.close()


def test_a_cycle_needs_enough_frames():
    with pytest.raises(ValueError, match="at least 8 frames"):
        PivotScene(CALIBRATION, BOARD, frames_per_cycle=4)
