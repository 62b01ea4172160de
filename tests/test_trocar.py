"""Trocar calibration (thesis §3.5, §4.1 and the pivot method): seeded simulated pivoting, rendered boards, errors."""

import argparse
import dataclasses
import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.calibration.checkerboard import Board, find_corners
from snreg.calibration.pivot import (board_from_camera_pose, imu_camera_rotation, imu_from_camera_transform,
                                     pivot_calibration, reference_trocar_from_camera)
from snreg.calibration.trocar import arc_distance, known_spot_distance, manual_distance
from snreg.camera import save_calibration, thesis_calibration
from snreg.chain import ChainCalibration
from snreg.cli.trocar import add_trocar_parser
from snreg.demo.board_render import render_stereo_board
from snreg.errors import UserError
from snreg.geometry import euler_from_rotation, invert, make_transform, rotation_distance_deg

TROCAR_CAMERA_MM = 158.0   # thesis Table 3
IMU_TROCAR_MM = 452.0      # thesis Table 2 (median)
BOARD = Board(9, 6, 10.0)
BOARD_DISTANCE_MM = 250.0  # camera to board in the reference pose
IMU_FROM_CAMERA = Rotation.from_euler("ZYX", [30.0, -10.0, 100.0], degrees=True)
EARTH_FROM_TROCAR = Rotation.from_euler("ZYX", [12.0, 40.0, -3.0], degrees=True)
IMU_NOISE_DEG = 0.1


def pivoting(n, seed, tilt_x=10.0, tilt_y=20.0, roll=30.0):
    """(n, 4, 4) ``trocar_from_camera``: the endoscope tilted about the pivot and rolled, camera 158 mm beyond it."""
    rng = np.random.default_rng(seed)
    angles = np.c_[rng.uniform(-tilt_x, tilt_x, n), rng.uniform(-tilt_y, tilt_y, n), rng.uniform(-roll, roll, n)]
    turn = Rotation.from_euler("xyz", angles, degrees=True)
    return make_transform(turn.as_matrix(), turn.apply([0.0, 0.0, TROCAR_CAMERA_MM]))


def trocar_from_board():
    """The still board facing the camera, its centre on the trocar axis 250 mm ahead of the camera."""
    centre = np.array([(BOARD.cols - 1) / 2.0, (BOARD.rows - 1) / 2.0, 0.0]) * BOARD.square_mm
    return make_transform(np.eye(3), np.array([0.0, 0.0, TROCAR_CAMERA_MM + BOARD_DISTANCE_MM]) - centre)


def imu_orientations(trocar_from_camera, seed):
    """``earth_from_imu`` per pose for the known IMU-camera rotation, with 0.1 degree noise."""
    rng = np.random.default_rng(seed)
    exact = EARTH_FROM_TROCAR * Rotation.from_matrix(trocar_from_camera[:, :3, :3]) * IMU_FROM_CAMERA.inv()
    return Rotation.from_rotvec(np.radians(IMU_NOISE_DEG) * rng.normal(size=(len(exact), 3))) * exact


def perturbed(poses, seed, rotation_deg=0.05, translation_mm=0.2):
    rng = np.random.default_rng(seed)
    out = poses.copy()
    noise = Rotation.from_rotvec(np.radians(rotation_deg) * rng.normal(size=(len(poses), 3)))
    out[:, :3, :3] = (noise * Rotation.from_matrix(poses[:, :3, :3])).as_matrix()
    out[:, :3, 3] += rng.normal(0.0, translation_mm, (len(poses), 3))
    return out


@pytest.fixture(scope="module")
def calib():
    return thesis_calibration().scaled(0.5)


@pytest.fixture(scope="module")
def rendered(calib):
    """20 rendered left views of the still board while pivoting: (trocar_from_camera, images, IMU orientations)."""
    trocar_from_camera = pivoting(20, seed=3)
    images = [render_stereo_board(calib, BOARD, invert(pose) @ trocar_from_board(), noise_sigma=2.0,
                                  blur_sigma=0.7, seed=20 + k)[0] for k, pose in enumerate(trocar_from_camera)]
    return trocar_from_camera, images, imu_orientations(trocar_from_camera, seed=4)


def test_pivot_from_exact_poses_is_exact():
    trocar_from_camera = pivoting(10, seed=1)
    result = pivot_calibration(invert(trocar_from_board()) @ trocar_from_camera)
    assert np.allclose(result.pivot_camera_mm, [0.0, 0.0, -TROCAR_CAMERA_MM], atol=1e-6)
    assert np.allclose(result.pivot_board_mm, invert(trocar_from_board())[:3, 3], atol=1e-6)
    assert result.rms_mm < 1e-6 and result.inliers.all() and result.verdict == "good"
    assert np.allclose(reference_trocar_from_camera(result) @ [0, 0, 0, 1], [0, 0, TROCAR_CAMERA_MM, 1], atol=1e-6)
    tilted = result.pivot_camera_mm + [8.0, -5.0, 0.0]   # a pivot off the optical axis (an angled scope)
    reference = reference_trocar_from_camera(dataclasses.replace(result, pivot_camera_mm=tilted))
    assert np.allclose(reference @ [*tilted, 1], [0, 0, 0, 1]) and np.allclose(reference[:2, 3], 0.0)


def test_pivot_and_imu_rotation_from_noisy_poses_with_outliers():
    trocar_from_camera = pivoting(40, seed=2)
    poses = perturbed(invert(trocar_from_board()) @ trocar_from_camera, seed=5)
    poses[[7, 23], :3, 3] += [[6.0, 0.0, 0.0], [0.0, -4.0, 3.0]]  # the board was bumped twice
    result = pivot_calibration(poses)
    assert abs(result.trocar_camera_mm - TROCAR_CAMERA_MM) < 0.3
    assert np.flatnonzero(~result.inliers).tolist() == [7, 23]
    assert result.rms_mm < 0.5 and result.verdict == "good"
    assert result.tilt_range_deg > 30.0
    hand_eye = imu_camera_rotation(imu_orientations(trocar_from_camera, seed=6)[result.inliers], poses[result.inliers])
    assert rotation_distance_deg(hand_eye.imu_from_camera, IMU_FROM_CAMERA.as_matrix()) < 0.3  # 20 seeds: 0.02-0.17
    assert 0.05 < hand_eye.rms_deg < 0.5


@pytest.mark.slow
def test_pivot_from_rendered_board_images(calib, rendered):
    trocar_from_camera, images, imu = rendered
    poses = np.array([board_from_camera_pose(find_corners(image, BOARD), BOARD, calib.K1, calib.D1) for image in images])
    truth = invert(trocar_from_board()) @ trocar_from_camera
    assert rotation_distance_deg(poses, truth).max() < 0.2
    result = pivot_calibration(poses)
    assert abs(result.trocar_camera_mm - TROCAR_CAMERA_MM) < 1.0
    assert np.linalg.norm(result.pivot_camera_mm[:2]) < 1.0
    assert result.verdict == "good" and result.n_used >= 16
    hand_eye = imu_camera_rotation(imu[result.inliers], poses[result.inliers])
    assert rotation_distance_deg(hand_eye.imu_from_camera, IMU_FROM_CAMERA.as_matrix()) < 0.5


def test_imu_from_camera_puts_the_imu_on_the_shaft_behind_the_pivot():
    result = pivot_calibration(invert(trocar_from_board()) @ pivoting(8, seed=1))
    imu_from_camera = imu_from_camera_transform(IMU_FROM_CAMERA.as_matrix(), result, IMU_TROCAR_MM)
    imu_in_camera = invert(imu_from_camera)[:3, 3]
    assert np.allclose(imu_in_camera, [0.0, 0.0, -(TROCAR_CAMERA_MM + IMU_TROCAR_MM)], atol=1e-5)
    assert np.allclose(imu_from_camera[:3, :3], IMU_FROM_CAMERA.as_matrix())


def test_a_recording_that_does_not_pivot_is_judged_bad():
    rng = np.random.default_rng(8)
    poses = make_transform(Rotation.random(12, random_state=9).as_matrix(), rng.uniform(-50, 50, (12, 3)))
    assert pivot_calibration(poses).verdict == "bad"


def test_a_small_tilt_range_is_judged_bad():
    poses = perturbed(invert(trocar_from_board()) @ pivoting(20, seed=1, tilt_x=1.5, tilt_y=1.5, roll=40.0), seed=2)
    result = pivot_calibration(poses)
    assert result.tilt_range_deg < 5.0 and result.verdict == "bad"


@pytest.mark.parametrize("poses, message", [
    (np.tile(np.eye(4), (3, 1, 1)), "need at least 4"),
    (make_transform(np.tile(np.eye(3), (6, 1, 1)), np.arange(18.0).reshape(6, 3)), "turned at most 0.00 degrees"),
    (make_transform(Rotation.from_euler("z", [[0], [10], [20], [30], [40]], degrees=True).as_matrix(), np.zeros((5, 3))),
     "single axis"),
    (np.zeros((5, 4)), "shape"),
])
def test_pivot_calibration_rejects_unusable_poses(poses, message):
    with pytest.raises(ValueError, match=message):
        pivot_calibration(poses)


def test_imu_rotation_rejects_mismatched_or_one_axis_recordings():
    poses = invert(trocar_from_board()) @ pivoting(10, seed=1)
    with pytest.raises(ValueError, match="9 IMU orientations for 10 camera poses"):
        imu_camera_rotation(Rotation.identity(9), poses)
    turns = Rotation.from_euler("z", np.linspace(0, 40, 6)[:, None], degrees=True)
    with pytest.raises(ValueError, match="one axis only"):
        imu_camera_rotation(turns, turns.as_matrix())
    with pytest.raises(ValueError, match="turned 2 degrees or more"):
        imu_camera_rotation(Rotation.identity(5), np.tile(np.eye(3), (5, 1, 1)))


def test_imu_rotation_uses_evenly_chosen_poses_of_a_long_recording():
    trocar_from_camera = pivoting(300, seed=11)
    hand_eye = imu_camera_rotation(imu_orientations(trocar_from_camera, seed=12), trocar_from_camera)
    assert hand_eye.n_pairs <= 200 * 199 // 2
    assert rotation_distance_deg(hand_eye.imu_from_camera, IMU_FROM_CAMERA.as_matrix()) < 0.05


def imu_swing(n, seed, noise_mm=0.0, noise_deg=0.0):
    """IMU positions (n, 3) and orientations swinging about the pivot 452 mm below it, no roll (thesis Fig 9).

    Each step turns by 1.5 to 4 degrees about an axis across the current shaft, so eq. 14 holds exactly.
    """
    rng = np.random.default_rng(seed)
    turns = [Rotation.identity()]
    for _ in range(n - 1):
        shaft = turns[-1].apply([0.0, 0.0, -1.0])
        axis = np.cross(shaft, rng.normal(size=3))
        angle = rng.choice([-1.0, 1.0]) * rng.uniform(1.5, 4.0)
        turns.append(Rotation.from_rotvec(np.radians(angle) * axis / np.linalg.norm(axis)) * turns[-1])
    turn = Rotation.concatenate(turns)
    positions = turn.apply([0.0, 0.0, -IMU_TROCAR_MM]) + rng.normal(0.0, noise_mm, (n, 3))
    return positions, Rotation.from_rotvec(np.radians(noise_deg) * rng.normal(size=(n, 3))) * turn


def test_arc_method_recovers_the_imu_trocar_distance():
    positions, orientations = imu_swing(200, seed=1)
    exact = arc_distance(positions, orientations)
    assert exact.method == "arc" and abs(exact.distance_mm - IMU_TROCAR_MM) < 1e-6 and exact.iqr_mm < 1e-6
    positions, orientations = imu_swing(400, seed=2, noise_mm=0.3, noise_deg=0.1)
    noisy = arc_distance(positions, orientations.as_matrix())
    assert abs(noisy.distance_mm - IMU_TROCAR_MM) < 5.0
    assert noisy.q25_mm < IMU_TROCAR_MM < noisy.q75_mm


def test_arc_method_keeps_only_pairs_that_moved_and_turned():
    positions, orientations = imu_swing(6, seed=3)
    positions = np.insert(positions, 3, positions[2], axis=0)    # a sample that neither moved nor turned
    orientations = Rotation.concatenate([orientations[:3], orientations[2:3], orientations[3:]])
    estimate = arc_distance(positions, orientations)
    assert estimate.n_used == 5 and np.allclose(estimate.values_mm, IMU_TROCAR_MM)
    assert arc_distance(positions, orientations, min_angle_deg=3.0).n_used < 5
    with pytest.raises(ValueError, match="moved more than 1 mm and turned more than 1 degrees"):
        arc_distance(positions[2:4], orientations[2:4])
    with pytest.raises(ValueError, match="7 positions need 7 orientations"):
        arc_distance(positions, orientations[:6])


def test_known_spot_method_recovers_the_trocar_camera_distance():
    rng = np.random.default_rng(4)
    trocar_from_camera = pivoting(60, seed=4)
    spots_trocar = np.array([[30.0, 20.0, 230.0], [-25.0, 10.0, 240.0]])  # two markers, as in the thesis
    known = np.linalg.norm(spots_trocar, axis=1)
    spots = np.concatenate([(invert(pose)[:3, :3] @ spots_trocar.T).T + invert(pose)[:3, 3] for pose in trocar_from_camera])
    distances = np.tile(known, len(trocar_from_camera))
    exact = known_spot_distance(spots, distances)
    assert exact.method == "known-spot" and exact.n_used == 120 and np.allclose(exact.values_mm, TROCAR_CAMERA_MM)
    noisy = known_spot_distance(spots + rng.normal(0.0, 0.3, spots.shape), distances)
    assert abs(noisy.distance_mm - TROCAR_CAMERA_MM) < 0.3 and noisy.iqr_mm < 1.0


def test_known_spot_method_rejects_bad_input():
    with pytest.raises(ValueError, match="one per spot"):
        known_spot_distance(np.zeros((3, 3)), [1.0, 2.0])
    with pytest.raises(ValueError, match="nearer the camera axis"):
        known_spot_distance(np.array([[100.0, 0.0, 50.0]]), 50.0)
    with pytest.raises(ValueError, match="shape"):
        known_spot_distance(np.zeros((3, 2)), 50.0)


def test_manual_distance():
    estimate = manual_distance(460.0)
    assert (estimate.distance_mm, estimate.iqr_mm, estimate.n_used, estimate.method) == (460.0, 0.0, 1, "manual")
    with pytest.raises(ValueError, match="positive"):
        manual_distance(-1.0)


def run_trocar(argv):
    parser = argparse.ArgumentParser(prog="snreg")
    calibrate = parser.add_subparsers(dest="command", required=True).add_parser("calibrate")
    add_trocar_parser(calibrate.add_subparsers(dest="calibrate_command", required=True))
    args = parser.parse_args(["calibrate", "trocar", *argv])
    return args.func(args)


def test_command_manual_prints_and_writes_the_thesis_chain(tmp_path, capsys):
    output = tmp_path / "chain.json"
    assert run_trocar(["manual", "--imu-trocar", "460", "--trocar-camera", "158", "-o", str(output)]) == 0
    printed = json.loads(capsys.readouterr().out)
    chain = ChainCalibration.from_dict(json.loads(output.read_text()))
    assert printed["method"] == "manual" and printed["imu_from_camera"][2][3] == 618.0
    assert (chain.imu_trocar_mm, chain.trocar_camera_mm) == (460.0, 158.0)
    with pytest.raises(UserError, match="positive"):
        run_trocar(["manual", "--imu-trocar", "460", "--trocar-camera", "-5"])


@pytest.mark.slow
def test_command_pivot_on_image_files(tmp_path, capsys, calib, rendered):
    trocar_from_camera, images, imu = rendered
    for k, image in enumerate(images):
        cv2.imwrite(str(tmp_path / f"left{k}.png"), image)
    cv2.imwrite(str(tmp_path / "left99.png"), np.full_like(images[0], 128))  # no board in view
    save_calibration(calib, tmp_path / "calib.yaml")
    rows = [euler_from_rotation(r) for r in imu.as_matrix()] + [(0.0, 0.0, 0.0)]
    (tmp_path / "imu.csv").write_text("# per image\nt_host_s,yaw,pitch,roll\n" +
                                      "".join(f"{k},{y},{p},{r}\n" for k, (y, p, r) in enumerate(rows)))
    common = ["pivot", "--images", str(tmp_path / "left*.png"), "--board", "9x6", "--square", "10",
              "--calib", str(tmp_path / "calib.yaml")]
    assert run_trocar([*common, "--imu-csv", str(tmp_path / "imu.csv"), "-o", str(tmp_path / "chain.json")]) == 0
    out = capsys.readouterr().out
    assert "board not found in (skipped): left99.png" in out and "verdict: good" in out
    assert "IMU-camera rotation (imu_from_camera; yaw, pitch, roll): 30." in out or "29.9" in out
    chain = ChainCalibration.from_dict(json.loads((tmp_path / "chain.json").read_text()))
    assert abs(chain.trocar_camera_mm - TROCAR_CAMERA_MM) < 1.0 and chain.imu_trocar_mm == 460.0
    assert rotation_distance_deg(chain.imu_from_camera, IMU_FROM_CAMERA.as_matrix()) < 0.5
    (tmp_path / "short.csv").write_text("yaw,pitch,roll\n0,0,0\n")
    with pytest.raises(UserError, match="1 IMU rows for 21 images"):
        run_trocar([*common, "--imu-csv", str(tmp_path / "short.csv")])
    with pytest.raises(UserError, match="COLSxROWS"):
        run_trocar([*common[:4], "nine", *common[5:]])
    with pytest.raises(UserError, match="no files match"):
        run_trocar(["pivot", "--images", str(tmp_path / "none*.png"), *common[3:]])
