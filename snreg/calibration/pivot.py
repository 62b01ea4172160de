"""Pivot calibration of the endoscope about its trocar, and the IMU-camera rotation, from camera poses.

The better alternative to the thesis's arc and known-spot methods (§3.5, §4.1;
:mod:`snreg.calibration.trocar`). A checkerboard lies still in view while the endoscope is pivoted
about the trocar. Every camera pose ``board_from_camera_i = [R_i | t_i]`` (``cv2.solvePnP`` on the
detected corners) keeps the pivot point fixed: ``R_i p_camera + t_i = p_board``. Stacked over the
poses this is the standard pivot calibration (as PLUS / SlicerIGT)::

    [R_i | -I] [p_camera; p_board] = -t_i        (3n equations, 6 unknowns, linear least squares)

so the trocar-camera distance is ``|p_camera|`` directly, with no assumption that the pivot lies on
the optical axis, and the residuals say how well the recording pivoted. Poses whose residual exceeds
``outlier_factor`` times the median residual of all poses are dropped and the fit repeated. (Measured
on rendered boards, solvePnP's residuals have a long tail: 3 times the median of the inliers, iterated,
dropped up to a quarter of good poses; 4 times that of all poses drops about one in twenty.)

With the IMU orientation recorded beside each image, the same recording gives the IMU-camera
rotation ``X = imu_from_camera`` (the thesis set it to the identity by eye): the board is the
camera's world and the earth the IMU's, so for any two poses the relative rotations
``A = E_i^T E_j`` (IMU) and ``B = C_i^T C_j`` (camera) satisfy ``A X = X B`` (rotation hand-eye),
and their rotation vectors ``a = X b`` (equal angles, axes turned by X). ``X`` is the Wahba fit of
the paired rotation vectors (``scipy Rotation.align_vectors``; larger turns weigh more, as their
axes are better defined). OpenCV 5's Python build has no ``calibrateHandEye``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from snreg.calibration.checkerboard import Board
from snreg.chain import reference_rotation
from snreg.geometry import invert, make_transform, rotation_angle_deg

__all__ = ["MIN_POSES", "PivotResult", "HandEyeRotation", "board_from_camera_pose", "pivot_calibration",
           "imu_camera_rotation", "reference_trocar_from_camera", "imu_from_camera_transform"]

MIN_POSES = 4
MIN_ROTATION_DEG = 2.0       # the poses must turn at least this much, or nothing is determined
GOOD_RMS_MM, BAD_RMS_MM = 1.0, 3.0          # verdict thresholds: RMS residual,
GOOD_SD_MM, BAD_SD_MM = 0.5, 2.0            # standard error of the distance,
GOOD_TILT_DEG = 15.0         # tilt range of the shaft (less is bad: PLUS/IGSIO's MinimumOrientationDifferenceDeg),
BAD_INLIER_FRACTION = 0.5                   # and the share of poses that agree
_RESIDUAL_FLOOR_MM = 0.1     # residuals below this are never called outliers
_MAX_HAND_EYE_POSES = 200    # all pairs of at most this many poses (evenly chosen) enter the rotation fit


@dataclass(frozen=True, eq=False)
class PivotResult:
    """A pivot calibration; mm, degrees.

    ``pivot_camera_mm`` (3,) and ``pivot_board_mm`` (3,): the pivot point in the camera and board
    frames. ``residuals_mm`` (n,): every pose's ``|R_i p_camera + t_i - p_board|``; ``inliers`` (n,)
    bool: the poses kept. ``rms_mm``: RMS residual of the inliers. ``tilt_range_deg``: the largest
    angle between two inlier directions of the shaft (pivot to camera) in the board frame, the spread
    that determines the distance (turning about the shaft does not). ``distance_sd_mm``: standard
    error of the distance from the least-squares covariance. ``verdict``: "good", "check" or "bad",
    with ``advice``: one sentence why.
    """

    pivot_camera_mm: np.ndarray
    pivot_board_mm: np.ndarray
    residuals_mm: np.ndarray
    inliers: np.ndarray
    rms_mm: float
    tilt_range_deg: float
    distance_sd_mm: float
    verdict: str
    advice: str

    @property
    def trocar_camera_mm(self) -> float:
        """Distance from the pivot (trocar) to the camera origin, mm."""
        return float(np.linalg.norm(self.pivot_camera_mm))

    @property
    def n_used(self) -> int:
        return int(self.inliers.sum())


@dataclass(frozen=True, eq=False)
class HandEyeRotation:
    """The IMU-camera rotation ``imu_from_camera`` (3, 3), with the per-pair angle residuals (m,), degrees."""

    imu_from_camera: np.ndarray
    residuals_deg: np.ndarray

    @property
    def rms_deg(self) -> float:
        return float(np.sqrt(np.mean(self.residuals_deg ** 2)))

    @property
    def n_pairs(self) -> int:
        return len(self.residuals_deg)


def board_from_camera_pose(corners: np.ndarray, board: Board, K: np.ndarray, D: np.ndarray) -> np.ndarray:
    """(4, 4) ``board_from_camera`` from detected corners (cols * rows, 2) px, intrinsics K (3, 3), D (1, 5).

    ``cv2.solvePnP`` with IPPE (exact for a plane) refined by Levenberg-Marquardt, then inverted.
    """
    objects = board.object_points().astype(np.float64)
    image = np.asarray(corners, dtype=np.float64).reshape(-1, 1, 2)
    K, D = np.asarray(K, dtype=np.float64), np.asarray(D, dtype=np.float64).reshape(1, -1)
    ok, rvec, tvec = cv2.solvePnP(objects, image, K, D, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise ValueError("cv2.solvePnP found no board pose for these corners")
    rvec, tvec = cv2.solvePnPRefineLM(objects, image, K, D, rvec, tvec)
    return invert(make_transform(cv2.Rodrigues(rvec)[0], tvec.ravel()))


def pivot_calibration(board_from_camera: np.ndarray, *, outlier_factor: float = 4.0,
                      max_iterations: int = 10) -> PivotResult:
    """Least-squares pivot point of camera poses (n, 4, 4) ``board_from_camera`` (mm) that pivot about a fixed point.

    Solves ``[R_i | -I] [p_camera; p_board] = -t_i`` (module docstring), drops poses whose residual
    exceeds ``outlier_factor`` times the median of all poses (and 0.1 mm) and refits, at most
    ``max_iterations`` times. Raises ``ValueError`` for fewer than :data:`MIN_POSES` poses, poses
    turning less than :data:`MIN_ROTATION_DEG`, or turns about a single axis (pivot undetermined).
    """
    poses = _poses(board_from_camera, "board_from_camera")
    rotation, translation = poses[:, :3, :3], poses[:, :3, 3]
    turned = float(rotation_angle_deg(np.swapaxes(rotation[:1], 1, 2) @ rotation).max())
    if turned < MIN_ROTATION_DEG:
        raise ValueError(f"the camera turned at most {turned:.2f} degrees from its first pose, need {MIN_ROTATION_DEG:g}; "
                         "pivot the endoscope about the trocar in two directions while the board stays in view")
    system = np.concatenate([rotation, -np.broadcast_to(np.eye(3), rotation.shape)], axis=2)  # (n, 3, 6)
    inliers = np.ones(len(poses), bool)
    solution, covariance, residuals = _fit(system, translation, inliers)
    for _ in range(max_iterations):
        threshold = max(outlier_factor * float(np.median(residuals)), _RESIDUAL_FLOOR_MM)
        keep = residuals <= threshold
        if keep.sum() < MIN_POSES or np.array_equal(keep, inliers):
            break
        inliers = keep
        solution, covariance, residuals = _fit(system, translation, inliers)
    p_camera, p_board = solution[:3], solution[3:]
    rms = float(np.sqrt(np.mean(residuals[inliers] ** 2)))
    along = p_camera / np.linalg.norm(p_camera)
    sd = float(np.sqrt(max(along @ covariance[:3, :3] @ along, 0.0)))
    shaft = -rotation[inliers] @ along
    tilt = float(np.degrees(np.arccos(np.clip((shaft @ shaft.T).min(), -1.0, 1.0))))
    verdict, advice = _verdict(rms, tilt, sd, inliers.mean())
    return PivotResult(p_camera, p_board, residuals, inliers, rms, tilt, sd, verdict, advice)


def imu_camera_rotation(earth_from_imu, board_from_camera: np.ndarray, *, min_angle_deg: float = 2.0) -> HandEyeRotation:
    """``imu_from_camera`` rotation from paired IMU and camera orientations (module docstring).

    ``earth_from_imu``: (n, 3, 3) or a scipy ``Rotation`` of length n, the IMU orientation at each
    pose (sensor to earth, as an AHRS gives it); ``board_from_camera``: (n, 4, 4) or (n, 3, 3).
    All pairs of poses (of at most 200 evenly chosen) whose camera turned at least ``min_angle_deg``
    enter the fit. Heading drift of a 6-axis IMU between the poses of a pair enters as error.
    Raises ``ValueError`` for mismatched lengths, too few poses or pairs, or turns about one axis only.
    """
    camera = Rotation.from_matrix(_poses(board_from_camera, "board_from_camera")[:, :3, :3])
    imu = earth_from_imu if isinstance(earth_from_imu, Rotation) else Rotation.from_matrix(
        np.asarray(earth_from_imu, dtype=float).reshape(-1, 3, 3))
    if imu.single or len(imu) != len(camera):
        raise ValueError(f"{1 if imu.single else len(imu)} IMU orientations for {len(camera)} camera poses; "
                         "give one IMU orientation per pose")
    chosen = np.unique(np.linspace(0, len(camera) - 1, min(len(camera), _MAX_HAND_EYE_POSES)).round().astype(int))
    i, j = np.triu_indices(len(chosen), k=1)
    i, j = chosen[i], chosen[j]
    camera_turn = (camera[i].inv() * camera[j]).as_rotvec()
    imu_turn = (imu[i].inv() * imu[j]).as_rotvec()
    use = np.degrees(np.linalg.norm(camera_turn, axis=1)) >= min_angle_deg
    if use.sum() < 2:
        raise ValueError(f"only {use.sum()} pairs of poses turned {min_angle_deg:g} degrees or more; "
                         "turn the endoscope more while recording")
    axes = camera_turn[use] / np.linalg.norm(camera_turn[use], axis=1, keepdims=True)
    singular = np.linalg.svd(axes, compute_uv=False)
    if singular[1] < np.sin(np.radians(min_angle_deg)) * singular[0]:
        raise ValueError("the camera turned about one axis only, which leaves the IMU-camera rotation undetermined; "
                         "tilt the endoscope in two directions")
    fit, _ = Rotation.align_vectors(imu_turn[use], camera_turn[use])
    predicted = fit * (camera[i[use]].inv() * camera[j[use]]) * fit.inv()
    residuals = np.degrees((predicted.inv() * (imu[i[use]].inv() * imu[j[use]])).magnitude())
    return HandEyeRotation(fit.as_matrix(), residuals)


def reference_trocar_from_camera(pivot: PivotResult) -> np.ndarray:
    """(4, 4) ``trocar_from_camera`` in the reference pose: origin at the pivot, z along the shaft (docs/design.md, Conventions)."""
    rotation = reference_rotation(-pivot.pivot_camera_mm)
    return make_transform(rotation, -rotation @ pivot.pivot_camera_mm)


def imu_from_camera_transform(imu_from_camera_rotation: np.ndarray, pivot: PivotResult, imu_trocar_mm: float) -> np.ndarray:
    """(4, 4) ``imu_from_camera`` with the IMU on the shaft ``imu_trocar_mm`` behind the pivot.

    The shaft is the line from the camera through the pivot, so the IMU sits in the camera frame at
    ``p_camera (1 + imu_trocar_mm / |p_camera|)``; the rotation (3, 3) comes from
    :func:`imu_camera_rotation` or is the identity (the thesis's visual alignment).
    """
    if not imu_trocar_mm >= 0:
        raise ValueError(f"the IMU-trocar distance must be zero or positive (mm), got {imu_trocar_mm}")
    rotation = np.asarray(imu_from_camera_rotation, dtype=float)[:3, :3]
    imu_in_camera = pivot.pivot_camera_mm * (1.0 + imu_trocar_mm / pivot.trocar_camera_mm)
    return make_transform(rotation, -rotation @ imu_in_camera)


def _poses(transforms: np.ndarray, name: str) -> np.ndarray:
    """Validate (n, 4, 4) or (n, 3, 3) finite poses, n >= MIN_POSES; returns (n, 4, 4) float."""
    transforms = np.asarray(transforms, dtype=float)
    if transforms.ndim != 3 or transforms.shape[1:] not in ((4, 4), (3, 3)):
        raise ValueError(f"{name} must have shape (n, 4, 4), got {transforms.shape}")
    if len(transforms) < MIN_POSES:
        raise ValueError(f"{len(transforms)} camera poses given, need at least {MIN_POSES}")
    if not np.isfinite(transforms).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    if transforms.shape[1] == 3:
        transforms = make_transform(transforms, np.zeros(transforms.shape[:1] + (3,)))
    return transforms


def _fit(system: np.ndarray, translation: np.ndarray, inliers: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares solution (6,) of the inlier rows of (n, 3, 6) x = -t (n, 3), its covariance (6, 6)
    and every pose's residual (n,), mm."""
    a, b = system[inliers].reshape(-1, 6), -translation[inliers].reshape(-1)
    solution, _, rank, _ = np.linalg.lstsq(a, b, rcond=None)
    if rank < 6:
        raise ValueError("the camera turned about a single axis, which leaves the pivot undetermined; "
                         "tilt the endoscope in two directions about the trocar")
    variance = float(np.sum((a @ solution - b) ** 2)) / max(len(b) - 6, 1)
    residuals = np.linalg.norm(np.einsum("nij,j->ni", system, solution) + translation, axis=1)
    return solution, variance * np.linalg.inv(a.T @ a), residuals


def _verdict(rms_mm: float, tilt_deg: float, sd_mm: float, inlier_fraction: float) -> tuple[str, str]:
    """("good" | "check" | "bad", one sentence) from the GOOD_* and BAD_* thresholds."""
    if tilt_deg < GOOD_TILT_DEG:
        return "bad", (f"the shaft's orientation spread is only {tilt_deg:.1f} degrees, under the {GOOD_TILT_DEG:g} degrees "
                       "a pivot calibration needs (as PLUS/IGSIO); pivot it further in two directions and record again")
    if rms_mm > BAD_RMS_MM or sd_mm > BAD_SD_MM:
        return "bad", (f"residual {rms_mm:.2f} mm, distance uncertainty {sd_mm:.2f} mm: the endoscope did not pivot "
                       "about one point or the board moved; record again")
    if inlier_fraction < BAD_INLIER_FRACTION:
        return "bad", f"only {inlier_fraction:.0%} of the poses agree on a pivot; keep the board still and record again"
    if rms_mm > GOOD_RMS_MM or sd_mm > GOOD_SD_MM:
        return "check", (f"residual {rms_mm:.2f} mm, uncertainty {sd_mm:.2f} mm, tilt range {tilt_deg:.1f} degrees: "
                         "usable, but more tilt and a steadier board would help")
    return "good", f"residual {rms_mm:.2f} mm, uncertainty {sd_mm:.2f} mm over a tilt range of {tilt_deg:.1f} degrees"
