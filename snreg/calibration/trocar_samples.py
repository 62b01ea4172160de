"""Live trocar calibration data and fits: board poses paired with IMU orientations, and what they give.

Why: the trocar wizard (``snreg_gui.trocar_wizard``) runs these in worker threads, since corner detection
(~80 ms a frame at half the thesis resolution) and the fits must stay off the GUI thread (DESIGN.md §5);
they hold no Qt, so they live in the core. :func:`capture_samples` is the generator the capture worker
runs; :func:`fit_pivot` and :func:`fit_arc` are what the fit Workers run on a copy of the samples. All the
computing is in :mod:`snreg.calibration.pivot` and :mod:`snreg.calibration.trocar`; this module only feeds
them, the same way ``snreg calibrate trocar`` does from image files.

A sample is a frame where the board was found, with the IMU orientation taken right after the frame was
read (the IMU at the frame's host time, to within one read), kept when the camera has turned at least
:data:`MIN_SAMPLE_TURN_DEG` since the last sample: holding still adds nothing, and consecutive samples
then meet the arc method's 1 degree threshold (thesis eq. 14).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from snreg.calibration.checkerboard import Board, find_corners
from snreg.calibration.pivot import (HandEyeRotation, PivotResult, board_from_camera_pose, imu_camera_rotation,
                                     imu_from_camera_transform, pivot_calibration)
from snreg.calibration.trocar import DistanceEstimate, arc_distance
from snreg.camera import StereoCalibration
from snreg.chain import THESIS_IMU_TROCAR_MM, ChainCalibration
from snreg.geometry import rotation_distance_deg
from snreg.sources import FrameSource, SourceState

MIN_SAMPLE_TURN_DEG = 1.0     # the thesis's arc threshold: a turn smaller than this is not a new sample
MIN_ARC_PAIRS = 10            # a median of fewer swings is not worth a calibration
MAX_FRAME_RATE_HZ = 30.0      # a source that never blocks (a replay) is read no faster than a camera
DISPLAY_SCALE = 0.5           # the feed is shown at this fraction of the camera resolution
_WAIT_FOR_FRAME_S = 0.005


@dataclass(frozen=True, eq=False)
class PivotSample:
    """A board pose ``board_from_camera`` (4, 4) mm and the IMU's ``earth_from_imu`` (3, 3) and Euler angles
    (yaw, pitch, roll, degrees) taken with it, at host time ``t_host_ns`` (``time.perf_counter_ns``)."""

    frame_index: int
    t_host_ns: int
    board_from_camera: np.ndarray
    earth_from_imu: np.ndarray
    euler_deg: tuple[float, float, float]


@dataclass(frozen=True, eq=False)
class BoardFrame:
    """One processed frame: the left image for display (RGB at :data:`DISPLAY_SCALE`, corners drawn), the IMU
    angles taken with it, and the new sample or, when there is none, ``note`` saying why."""

    index: int
    display_rgb: np.ndarray
    euler_deg: tuple[float, float, float]
    board_found: bool
    sample: PivotSample | None
    note: str


@dataclass(frozen=True, eq=False)
class PivotFit:
    """The pivot method on ``n_samples`` samples: ``pivot`` (None with ``problem`` saying why), the IMU-camera
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


def capture_samples(make_source: Callable[[], FrameSource], imu, calibration: StereoCalibration, board: Board):
    """Generator: a :class:`BoardFrame` per left frame read; returns the source's problem when it ends.

    ``make_source`` is called here, in the worker thread (a renderer or camera may take time to open), and
    the source is closed here when the generator ends or is closed. ``imu.snapshot()`` must give
    ``earth_from_imu`` (3, 3) and ``euler_deg``.
    """
    source = make_source()
    try:
        last_pose = None
        while True:
            started = time.perf_counter()
            frame = source.read()
            if frame is None:
                if source.state is not SourceState.OPEN:
                    return source.problem
                time.sleep(_WAIT_FOR_FRAME_S)
                continue
            snapshot, t_host_ns = imu.snapshot(), time.perf_counter_ns()
            euler = tuple(float(a) for a in snapshot.euler_deg)
            corners = find_corners(frame.left, board)
            pose = _pose(corners, board, calibration)
            sample, note = None, "board not found: bring the whole board into the left view"
            if pose is not None:
                turned = float(rotation_distance_deg(pose, last_pose)) if last_pose is not None else np.inf
                if turned >= MIN_SAMPLE_TURN_DEG:
                    sample = PivotSample(frame.index, t_host_ns, pose, np.array(snapshot.earth_from_imu, dtype=float),
                                         euler)
                    last_pose, note = pose, ""
                else:
                    note = (f"turned {turned:.1f} of {MIN_SAMPLE_TURN_DEG:g} degrees since the last sample: "
                            "keep pivoting")
            yield BoardFrame(frame.index, _display(frame.left, corners, board), euler, pose is not None, sample, note)
            time.sleep(max(0.0, 1.0 / MAX_FRAME_RATE_HZ - (time.perf_counter() - started)))
    finally:
        source.close()


def fit_pivot(board_from_camera: np.ndarray, earth_from_imu: np.ndarray,
              imu_trocar_mm: float = THESIS_IMU_TROCAR_MM) -> PivotFit:
    """Pivot calibration of (n, 4, 4) poses, the IMU-camera rotation from the (n, 3, 3) orientations of its
    inlier poses, and the chain with the IMU ``imu_trocar_mm`` behind the pivot (it cancels out of the chain)."""
    n = len(board_from_camera)
    try:
        pivot = pivot_calibration(board_from_camera)
    except ValueError as err:
        return PivotFit(n, None, None, None, str(err), "")
    hand_eye, rotation_problem = None, ""
    try:
        hand_eye = imu_camera_rotation(earth_from_imu[pivot.inliers], board_from_camera[pivot.inliers])
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


def _pose(corners: np.ndarray | None, board: Board, calibration: StereoCalibration) -> np.ndarray | None:
    if corners is None:
        return None
    try:
        return board_from_camera_pose(corners, board, calibration.K1, calibration.D1)
    except ValueError:
        return None


def _display(left_bgr: np.ndarray, corners: np.ndarray | None, board: Board) -> np.ndarray:
    """The left frame as shown: RGB at :data:`DISPLAY_SCALE`, the found corners drawn in (OpenCV's row colours)."""
    small = cv2.resize(left_bgr, None, fx=DISPLAY_SCALE, fy=DISPLAY_SCALE, interpolation=cv2.INTER_AREA)
    rgb = cv2.cvtColor(small, cv2.COLOR_BGR2RGB)
    if corners is not None:
        scaled = (DISPLAY_SCALE * corners).astype(np.float32).reshape(-1, 1, 2)
        cv2.drawChessboardCorners(rgb, board.pattern_size, scaled, True)
    return rgb
