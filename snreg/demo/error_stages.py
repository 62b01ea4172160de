"""The stages of the error model that run the project's own code: stereo calibration from noisy board corners, the
IMU through the simulator and the fusion the app uses, the SPECT segmented by ``snreg preop``'s code.

Why: an error budget is only worth its name if each source's error comes out of the code that would make it in a
session (docs/design.md, Layout: demo/ holds everything simulated; the budget in simulation/ and the demo rig both call these).
Each function is seeded and returns the error it measured against the truth it simulated.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from snreg.calibration.checkerboard import THESIS_BOARD, Board
from snreg.calibration.stereo import calibrate_stereo_corners
from snreg.camera import StereoCalibration
from snreg.demo.board_render import random_board_poses, right_from_left
from snreg.demo.imu_motion import MotionProfile, rotate, still
from snreg.demo.imu_simulator import ImuSimulator, SensorModel
from snreg.demo.spect import spect_of_nodes
from snreg.imu.fusion import Fusion
from snreg.preop.segment import segment_nodes
from snreg.preop.volume import Volume

__all__ = ["estimate_calibration", "imu_session_errors", "spect_errors", "SpectErrors", "BOARD_DISTANCE_MM",
           "IMU_RATE_HZ", "IMU_STILL_START_S", "CAMERA_TURN_RATE_DPS"]

BOARD_DISTANCE_MM = (110.0, 250.0)   # snreg.demo.board_tour's distances: the board fills much of the image (§4.2.2)
IMU_RATE_HZ = 208.0                  # the LSM6DSOX output rate of the thesis set-up (snreg.simulation.imu)
IMU_STILL_START_S = 5.0              # held still at start: imufusion's 3 s start-up and the bias estimate
CAMERA_TURN_RATE_DPS = 10.0          # mean rate of the camera turn (the IMU experiment's turns, snreg.simulation.imu)
# imufusion's own defaults for the gyroscope bias (the thesis used imufusion, §3.1, settings not given): the run-time
# estimate with its 3 deg/s stationary threshold and no start-up average (the latter is snreg's addition)
_IMUFUSION_DEFAULTS = {"bias_stationary_threshold_dps": 3.0, "initial_bias_period_s": 0.0}


def estimate_calibration(cameras: StereoCalibration, *, views: int, corner_noise_px: float, seed: int,
                         board: Board = THESIS_BOARD) -> StereoCalibration:
    """The calibration ``snreg calibrate stereo``'s solver finds from ``views`` board poses seen by the true
    ``cameras``, each detected corner off by Gaussian noise of ``corner_noise_px`` per coordinate (seeded)."""
    rng = np.random.default_rng([seed, 11])
    poses = random_board_poses(cameras, board, views, int(rng.integers(1 << 31)), distance_mm=BOARD_DISTANCE_MM)
    objects = board.object_points().reshape(-1, 1, 3).astype(np.float64)
    corners = []
    for K, D, to_eye in ((cameras.K1, cameras.D1, np.eye(4)), (cameras.K2, cameras.D2, right_from_left(cameras))):
        eye = []
        for pose in poses:
            camera_from_board = to_eye @ pose
            rvec = cv2.Rodrigues(camera_from_board[:3, :3])[0]
            pixels = cv2.projectPoints(objects, rvec, camera_from_board[:3, 3], K, D)[0].reshape(-1, 2)
            eye.append(pixels + rng.normal(0.0, corner_noise_px, pixels.shape))
        corners.append(np.array(eye, dtype=np.float32))
    return calibrate_stereo_corners(corners[0], corners[1], board, cameras.image_size).calibration


def imu_session_errors(*, earth_from_imu_start: Rotation, turn_deg: float, store_poses: list[int], interval_s: float,
                       sensor: SensorModel, fusion: str, seed: int) -> np.ndarray:
    """(N, 3) rotation vectors (earth frame, radians) of the fused orientation's error at each store, relative to its
    error at the end of the still start (a common error rotates every node alike and registration absorbs it).

    The session as the thesis ran it: still ``IMU_STILL_START_S``, then one store every ``interval_s`` in the order
    given, the camera turning ``turn_deg`` about the vertical (a pan of the robot arm, which only the gyroscope sees)
    before the first store from pose 1. ``store_poses`` (N,): 0 or 1 per store. ``fusion``: "project" (the app's
    :class:`~snreg.imu.fusion.Fusion`) or "imufusion" (its defaults for the bias).
    """
    segments, store_times, t, pose = [still(IMU_STILL_START_S)], [], IMU_STILL_START_S, 0
    for node_pose in store_poses:
        if node_pose != pose and turn_deg > 0:
            turn = rotate((0.0, 0.0, 1.0), turn_deg * (1 if node_pose else -1), CAMERA_TURN_RATE_DPS)
            segments.append(turn)
            t += turn.duration_s
        pose = node_pose
        segments.append(still(interval_s))
        t += interval_s
        store_times.append(t - 0.5 / IMU_RATE_HZ)
    n = int(np.floor(t * IMU_RATE_HZ))
    simulator = ImuSimulator(MotionProfile(segments, initial=earth_from_imu_start), rate_hz=IMU_RATE_HZ, sensor=sensor,
                             seed=seed, n_samples=n)
    readings = simulator.readings(n)
    settings = _IMUFUSION_DEFAULTS if fusion == "imufusion" else {}
    engine = Fusion(IMU_RATE_HZ, gyroscope_range_dps=float(sensor.gyro_range_dps or 0), **settings)
    at = [int(round(IMU_STILL_START_S * IMU_RATE_HZ)) - 1] + [min(int(s * IMU_RATE_HZ), n - 1) for s in store_times]
    euler = engine.update_block(readings.t_device_us, readings.accel_g, readings.gyro_dps)
    fused = Rotation.from_euler("ZYX", euler[at], degrees=True)
    truth = simulator.profile.orientation(readings.t_s[at])
    error = fused * truth.inv()
    return (error[1:] * error[0].inv()).as_rotvec()


@dataclass(frozen=True, eq=False)
class SpectErrors:
    """Per source: the segmented centre minus the true source (N, 3) and the covariance the segmentation gave that
    centre (N, 3, 3), LPS mm and mm^2."""

    offsets: np.ndarray
    covariances: np.ndarray


def spect_errors(sources_lps: np.ndarray, *, voxel_mm: float, fwhm_mm: float, peak_counts: float,
                 seed: int) -> SpectErrors:
    """Each source's segmented centre's error and covariance for a SPECT of the ``sources`` at this voxel size,
    resolution and counts (Poisson, seeded), its grid placed at a random sub-voxel offset, segmented by
    :func:`~snreg.preop.segment.segment_nodes` (told the scanner's resolution) into as many nodes as sources."""
    sources = np.asarray(sources_lps, float)
    rng = np.random.default_rng([seed, 13])
    centre = sources.mean(axis=0) + rng.uniform(-0.5, 0.5, 3) * voxel_mm
    shape = tuple(int(np.ceil(v)) for v in (np.ptp(sources, axis=0)[::-1] + 6 * fwhm_mm) / voxel_mm + 1)
    counts, origin = spect_of_nodes(sources, centre=centre, shape=shape, voxel_mm=voxel_mm, fwhm_mm=fwhm_mm,
                                    peak_counts=peak_counts, seed=int(rng.integers(1 << 31)))
    volume = Volume(counts, np.diag([voxel_mm, voxel_mm, voxel_mm, 1.0]) + np.c_[np.zeros((4, 3)), [*origin, 0]],
                    "NM")
    nodes = segment_nodes(volume, n_nodes=len(sources), resolution_mm=fwhm_mm).nodes
    distance = np.linalg.norm(sources[:, None, :] - nodes.xyz[None, :, :], axis=2)
    match = np.argmin(distance, axis=1)
    if len(set(match.tolist())) < len(sources):          # two sources took one hot spot: pair one-to-one
        match = linear_sum_assignment(distance)[1]
    return SpectErrors(nodes.xyz[match] - sources, nodes.cov[match])
