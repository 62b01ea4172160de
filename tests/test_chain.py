"""The camera-to-trocar chain (thesis §3.5, Fig 7-8): a trocar-frame point stays put while the endoscope pivots."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.calibration.pivot import imu_camera_rotation, imu_from_camera_transform, pivot_calibration
from snreg.chain import (ChainCalibration, camera_from_probe, camera_to_trocar, trocar_from_camera, trocar_from_imu,
                         trocar_from_probe)
from snreg.geometry import apply, invert, make_transform

TROCAR_CAMERA_MM = 158.0
IMU_FROM_CAMERA = Rotation.from_euler("ZYX", [-20.0, 5.0, 95.0], degrees=True)
EARTH_FROM_TROCAR = Rotation.from_euler("ZYX", [70.0, -30.0, 10.0], degrees=True)
BOARD_FROM_TROCAR = make_transform(np.eye(3), [-40.0, -25.0, -400.0])
NODES_TROCAR = np.array([[20.0, -15.0, 260.0], [-35.0, 10.0, 300.0], [5.0, 40.0, 240.0]])


def pivoting(n, seed):
    """(n, 4, 4) ``trocar_from_camera``, the first the reference pose (the trocar frame itself, shifted)."""
    rng = np.random.default_rng(seed)
    angles = np.c_[rng.uniform(-15, 15, n), rng.uniform(-20, 20, n), rng.uniform(-40, 40, n)]
    angles[0] = 0.0
    turn = Rotation.from_euler("xyz", angles, degrees=True)
    return make_transform(turn.as_matrix(), turn.apply([0.0, 0.0, TROCAR_CAMERA_MM]))


def earth_from_imu(trocar_from_camera, seed, noise_deg):
    rng = np.random.default_rng(seed)
    exact = EARTH_FROM_TROCAR * Rotation.from_matrix(trocar_from_camera[:, :3, :3]) * IMU_FROM_CAMERA.inv()
    return Rotation.from_rotvec(np.radians(noise_deg) * rng.normal(size=(len(exact), 3))) * exact


def calibrated_chain(seed, imu_trocar_mm=460.0):
    """A chain from a simulated pivot recording (poses with 0.05 degree / 0.2 mm noise, IMU with 0.1 degree)."""
    rng = np.random.default_rng(seed)
    recording = pivoting(30, seed)
    imu = earth_from_imu(recording, seed + 1, noise_deg=0.1)
    poses = BOARD_FROM_TROCAR @ recording
    noise = Rotation.from_rotvec(np.radians(0.05) * rng.normal(size=(len(poses), 3)))
    poses[:, :3, :3] = (noise * Rotation.from_matrix(poses[:, :3, :3])).as_matrix()
    poses[:, :3, 3] += rng.normal(0.0, 0.2, (len(poses), 3))
    pivot = pivot_calibration(poses)
    rotation = imu_camera_rotation(imu, poses).imu_from_camera
    return ChainCalibration(imu_from_camera_transform(rotation, pivot, imu_trocar_mm), imu_trocar_mm)


def test_the_thesis_chain_puts_camera_and_imu_on_the_trocar_axis():
    chain = ChainCalibration.manual()
    assert chain.trocar_camera_mm == pytest.approx(158.0) and chain.imu_trocar_mm == 460.0
    assert np.allclose(apply(trocar_from_camera(chain, np.eye(3)), np.zeros((1, 3))), [[0, 0, 158]])
    assert np.allclose(trocar_from_imu(chain, np.eye(3))[:3, 3], [0, 0, -460])
    tilted = Rotation.from_euler("x", [[10.0]], degrees=True)[0]   # 10 degrees: the camera swings 158 sin 10 sideways
    assert np.allclose(camera_to_trocar(chain, tilted, [0.0, 0.0, 0.0]),
                       158.0 * np.array([0.0, -np.sin(np.radians(10)), np.cos(np.radians(10))]))


def test_the_reference_pose_puts_an_angled_scope_on_the_trocar_z_axis():
    shaft = np.array([0.0, np.sin(np.radians(30.0)), np.cos(np.radians(30.0))])   # a 30 degree scope, camera frame
    chain = ChainCalibration(make_transform(IMU_FROM_CAMERA.as_matrix(), IMU_FROM_CAMERA.apply(618.0 * shaft)), 460.0)
    assert np.allclose(chain.shaft_camera, shaft)
    reference = EARTH_FROM_TROCAR * IMU_FROM_CAMERA.inv()
    chain = chain.with_reference(reference)
    assert np.allclose(camera_to_trocar(chain, reference, [[0.0, 0.0, 0.0], -158.0 * shaft]), [[0, 0, 158.0], [0, 0, 0]])
    assert np.allclose(trocar_from_imu(chain, reference)[:3, 3], [0, 0, -460.0])


def test_exact_chain_keeps_a_trocar_point_fixed_while_pivoting():
    recording = pivoting(25, seed=1)
    chain = ChainCalibration(make_transform(IMU_FROM_CAMERA.as_matrix(), IMU_FROM_CAMERA.apply([0, 0, 618.0])), 460.0)
    chain = chain.with_reference(earth_from_imu(recording[:1], 2, 0.0)[0])
    imu = earth_from_imu(recording, 2, noise_deg=0.0)
    for k, pose in enumerate(recording):
        seen = apply(invert(pose), NODES_TROCAR)
        assert np.allclose(camera_to_trocar(chain, imu[k], seen), NODES_TROCAR, atol=1e-9)


def test_calibrated_chain_keeps_a_trocar_point_fixed_within_the_noise():
    recording = pivoting(25, seed=3)
    imu = earth_from_imu(recording, 4, noise_deg=0.1)
    chain = calibrated_chain(seed=5).with_reference(imu[0])
    mapped = np.array([camera_to_trocar(chain, imu[k], apply(invert(pose), NODES_TROCAR))
                       for k, pose in enumerate(recording)])                    # (poses, nodes, 3)
    spread = np.linalg.norm(mapped - mapped.mean(axis=0), axis=2)
    error = np.linalg.norm(mapped - NODES_TROCAR, axis=2)
    # 0.1 degree of IMU noise per axis (0.16 in all) at ~270 mm from the pivot moves a node 0.75 mm; the
    # reference pose's noise tilts the whole frame. 5 seeds: spread max 1.1-1.6, RMS 0.6-0.7, error RMS 0.7-1.1 mm
    assert spread.max() < 2.0 and np.sqrt(np.mean(spread ** 2)) < 1.0
    assert np.sqrt(np.mean(error ** 2)) < 1.6


def test_the_imu_trocar_distance_cancels_out_of_the_chain():
    recording = pivoting(5, seed=6)
    imu = earth_from_imu(recording, 7, noise_deg=0.0)
    near, far = (calibrated_chain(seed=8, imu_trocar_mm=d).with_reference(imu[0]) for d in (300.0, 600.0))
    for k in range(5):
        assert np.allclose(trocar_from_camera(near, imu[k]), trocar_from_camera(far, imu[k]), atol=1e-9)
        assert not np.allclose(trocar_from_imu(near, imu[k]), trocar_from_imu(far, imu[k]))


def test_trocar_from_probe_composes_camera_from_probe():
    chain = ChainCalibration.manual().with_reference(EARTH_FROM_TROCAR)
    orientation = Rotation.from_euler("ZYX", [75.0, -25.0, 12.0], degrees=True)
    camera_from_probe = make_transform(Rotation.from_euler("x", [[30.0]], degrees=True)[0].as_matrix(), [5.0, -3.0, 80.0])
    composed = trocar_from_probe(chain, orientation, camera_from_probe)
    assert np.allclose(composed[:3, 3], camera_to_trocar(chain, orientation, camera_from_probe[:3, 3]))
    assert np.allclose(composed, trocar_from_camera(chain, orientation.as_matrix()) @ camera_from_probe)


@pytest.mark.parametrize("axis", [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.3, -0.8, -0.5]])
def test_camera_from_probe_puts_the_tip_at_the_origin_and_z_along_the_axis(axis):
    tip, axis = np.array([4.0, -7.0, 95.0]), np.asarray(axis) / np.linalg.norm(axis)
    pose = camera_from_probe(tip, axis)
    rotation = pose[:3, :3]
    assert np.allclose(rotation @ rotation.T, np.eye(3)) and np.isclose(np.linalg.det(rotation), 1.0)
    assert np.allclose(pose[:3, 3], tip) and np.allclose(rotation[:, 2], axis)
    assert np.allclose(pose @ [0.0, 0.0, 20.0, 1.0], [*(tip + 20.0 * axis), 1.0])      # 20 mm up the probe


def test_to_dict_from_dict_round_trip_through_json():
    chain = calibrated_chain(seed=9).with_reference(EARTH_FROM_TROCAR)
    data = json.loads(json.dumps(chain.to_dict()))
    assert set(data) == {"imu_from_camera", "trocar_from_earth", "imu_trocar_mm", "trocar_camera_mm"}
    again = ChainCalibration.from_dict(data)
    assert np.array_equal(again.imu_from_camera, chain.imu_from_camera)
    assert np.array_equal(again.trocar_from_earth, chain.trocar_from_earth)
    assert again.imu_trocar_mm == chain.imu_trocar_mm
    with pytest.raises(ValueError, match="lacks trocar_from_earth"):
        ChainCalibration.from_dict({k: v for k, v in data.items() if k != "trocar_from_earth"})
    with pytest.raises(ValueError, match="disagrees"):
        ChainCalibration.from_dict({**data, "trocar_camera_mm": data["trocar_camera_mm"] + 1.0})
    with pytest.raises(ValueError, match="not a rigid transform"):
        ChainCalibration.from_dict({**data, "imu_from_camera": (2 * np.eye(4)).tolist()})


def test_chain_rejects_bad_input():
    chain = ChainCalibration.manual()
    with pytest.raises(ValueError, match="between 0 and the IMU-camera distance"):
        ChainCalibration(chain.imu_from_camera, 700.0)
    with pytest.raises(ValueError, match="4x4"):
        ChainCalibration(np.eye(3), 10.0)
    with pytest.raises(ValueError, match="zero translation"):
        ChainCalibration(chain.imu_from_camera, 460.0, make_transform(np.eye(3), [1.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="one IMU orientation"):
        camera_to_trocar(chain, Rotation.identity(3), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="shape"):
        camera_to_trocar(chain, np.eye(2), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        camera_to_trocar(chain, np.eye(3), np.zeros((2, 4)))
    with pytest.raises(ValueError, match="not a rigid transform"):
        camera_to_trocar(chain, np.diag([1.0, 1.0, -1.0]), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="positive"):
        ChainCalibration.manual(460.0, 0.0)


def test_gravity_in_the_trocar_frame_is_the_imus_down_through_the_reference():
    """The IMU's earth frame has z up (at rest the accelerometer reads +1 g up), so down is EARTH_DOWN there and
    ``trocar_from_earth @ EARTH_DOWN`` in the trocar frame: at the reference pose, gravity as the camera sees it."""
    from snreg.chain import EARTH_DOWN
    from snreg.demo.imu_motion import MotionProfile, still
    from snreg.demo.imu_simulator import ImuSimulator
    from snreg.imu.fusion import fuse_arrays

    np.testing.assert_array_equal(ChainCalibration.manual().down_trocar, [0.0, 0.0, -1.0])     # identity reference
    held = Rotation.from_euler("ZYX", [0.0, 12.0, -97.0], degrees=True)          # an endoscope looking near level
    readings = ImuSimulator(MotionProfile([still(1.0)], held), seed=1).readings(208 * 6)
    fused = Rotation.from_euler("ZYX", fuse_arrays(readings.t_s, readings.gyro_dps, readings.accel_g)[-1], degrees=True)
    up = readings.accel_g[-400:].mean(axis=0)
    np.testing.assert_allclose(fused.apply(-up / np.linalg.norm(up)), EARTH_DOWN, atol=2e-3)
    chain = ChainCalibration.manual().with_reference(fused)
    np.testing.assert_allclose(chain.down_trocar, held.inv().apply(EARTH_DOWN), atol=2e-3)
    # pivoting moves the camera, not the trocar frame: gravity seen from the turned camera, carried back, is the same
    turned = Rotation.from_euler("xyz", [8.0, -15.0, 30.0], degrees=True)
    camera_down = (held * turned).inv().apply(EARTH_DOWN)
    np.testing.assert_allclose(trocar_from_camera(chain, held * turned)[:3, :3] @ camera_down, chain.down_trocar,
                               atol=1e-9)


def test_rigid_check_keeps_allclose_tolerances():
    """The chain's cheaper rigidity check (issue 36) accepts and refuses as ``np.allclose`` did: a last row or a
    rotation off by more than the tolerance is refused, one within it accepted."""
    chain = ChainCalibration.manual()
    rotation = Rotation.from_euler("ZYX", [20, -10, 5], degrees=True).as_matrix()
    for off, rigid in ((5e-9, True), (1e-6, False)):            # last row: allclose's atol 1e-8
        bad_row = make_transform(rotation, [1.0, 2.0, 3.0])
        bad_row[3, 0] = off
        assert (np.allclose(bad_row[3], [0, 0, 0, 1])) is rigid
        if rigid:
            trocar_from_probe(chain, np.eye(3), bad_row)
        else:
            with pytest.raises(ValueError, match="not a rigid transform"):
                trocar_from_probe(chain, np.eye(3), bad_row)
    for scale, rigid in ((1 + 2e-7, True), (1 + 1e-5, False)):   # rotation: R R^T = I within 1e-6 (+ rtol 1e-5)
        stretched = rotation * np.array([scale, 1.0, 1.0])[:, None]
        assert np.allclose(stretched @ stretched.T, np.eye(3), atol=1e-6) is rigid
        if rigid:
            camera_to_trocar(chain, stretched, np.zeros(3))
        else:
            with pytest.raises(ValueError, match="not a rigid transform"):
                camera_to_trocar(chain, stretched, np.zeros(3))
