"""The trocar calibration of a recording of camera poses and IMU orientations: the pivot method (over a board or
over tissue) and the arc method.

Why: the trocar wizard refits its live samples after each new one, in a worker thread, and shows what the
recording gives so far; these are the fits it runs, on plain arrays. All the computing is in
:mod:`snreg.calibration.pivot`, :mod:`snreg.calibration.tissue_pivot` and :mod:`snreg.calibration.trocar`; this
module only feeds them, the same way ``snreg calibrate trocar`` does from image files, and builds the
:class:`~snreg.chain.ChainCalibration`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.calibration.pivot import (HandEyeRotation, PivotResult, imu_camera_rotation, imu_from_camera_transform,
                                     pivot_calibration)
from snreg.calibration.tissue_pivot import tissue_pivot_calibration
from snreg.calibration.trocar import DistanceEstimate, arc_distance
from snreg.chain import THESIS_IMU_TROCAR_MM, ChainCalibration

__all__ = ["PivotFit", "ArcFit", "fit_pivot", "fit_tissue_pivot", "fit_arc", "MIN_ARC_PAIRS"]

MIN_ARC_PAIRS = 10            # a median of fewer swings is not worth a calibration


@dataclass(frozen=True, eq=False)
class PivotFit:
    """The pivot method on ``n_samples`` samples (board or tissue poses): ``pivot`` (None with ``problem`` saying why), the IMU-camera
    rotation ``hand_eye`` (None with ``rotation_problem``: the chain then assumes the identity, as the thesis
    did) and the resulting ``chain``."""

    n_samples: int
    pivot: PivotResult | None
    hand_eye: HandEyeRotation | None
    chain: ChainCalibration | None
    problem: str
    rotation_problem: str

    @property
    def acceptable(self) -> bool:
        return self.chain is not None and self.pivot.verdict != "bad"


@dataclass(frozen=True, eq=False)
class ArcFit:
    """The arc method (thesis eq. 14) on ``n_samples`` samples: the trocar-camera ``estimate`` (None with
    ``problem`` saying why) and the ``chain`` it gives with the axes aligned by eye, as in the thesis."""

    n_samples: int
    estimate: DistanceEstimate | None
    chain: ChainCalibration | None
    problem: str

    @property
    def acceptable(self) -> bool:
        return self.estimate is not None and self.estimate.n_used >= MIN_ARC_PAIRS


def fit_pivot(board_from_camera: np.ndarray, earth_from_imu: np.ndarray,
              imu_trocar_mm: float = THESIS_IMU_TROCAR_MM) -> PivotFit:
    """Pivot calibration of (n, 4, 4) board poses, the IMU-camera rotation from the (n, 3, 3) orientations of its
    inlier poses, and the chain with the IMU ``imu_trocar_mm`` behind the pivot (it cancels out of the chain)."""
    return _fit_poses(pivot_calibration, board_from_camera, earth_from_imu, imu_trocar_mm)


def fit_tissue_pivot(tissue_from_camera: np.ndarray, earth_from_imu: np.ndarray,
                     imu_trocar_mm: float = THESIS_IMU_TROCAR_MM) -> PivotFit:
    """:func:`fit_pivot` on (n, 4, 4) free camera poses over tissue, with the tissue method's verdict
    (:func:`~snreg.calibration.tissue_pivot.tissue_pivot_calibration`)."""
    return _fit_poses(tissue_pivot_calibration, tissue_from_camera, earth_from_imu, imu_trocar_mm)


def _fit_poses(calibrate, poses: np.ndarray, earth_from_imu: np.ndarray, imu_trocar_mm: float) -> PivotFit:
    """``calibrate`` (poses -> PivotResult) on the poses, the IMU-camera rotation of its inliers, and the chain."""
    n = len(poses)
    try:
        pivot = calibrate(poses)
    except ValueError as err:
        return PivotFit(n, None, None, None, str(err), "")
    hand_eye, rotation_problem = None, ""
    try:
        hand_eye = imu_camera_rotation(earth_from_imu[pivot.inliers], poses[pivot.inliers])
    except ValueError as err:
        rotation_problem = str(err)
    rotation = hand_eye.imu_from_camera if hand_eye is not None else np.eye(3)
    chain = ChainCalibration(imu_from_camera_transform(rotation, pivot, imu_trocar_mm), imu_trocar_mm)
    return PivotFit(n, pivot, hand_eye, chain, "", rotation_problem)


def fit_arc(board_from_camera: np.ndarray, earth_from_imu: np.ndarray,
            imu_trocar_mm: float = THESIS_IMU_TROCAR_MM) -> ArcFit:
    """The arc method on the camera origin in the board frame (a point on the shaft, swinging about the pivot)
    with the IMU orientations: the trocar-camera distance; the chain as :meth:`ChainCalibration.manual`."""
    n = len(board_from_camera)
    try:
        estimate = arc_distance(board_from_camera[:, :3, 3], earth_from_imu)
    except ValueError as err:
        return ArcFit(n, None, None, str(err))
    return ArcFit(n, estimate, ChainCalibration.manual(imu_trocar_mm, estimate.distance_mm), "")
