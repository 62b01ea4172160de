"""The trocar wizard's live capture: board poses paired with the IMU orientation taken with each frame.

Why: the trocar wizard runs this loop in a worker thread, since corner detection (~80 ms a frame at half the
thesis resolution) must stay off the GUI thread (docs/design.md, Habits); it holds no Qt, so it lives in the core.
:func:`capture_samples` is the generator the capture worker runs; :mod:`snreg.calibration.trocar_fit` fits
the samples it keeps.

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
from snreg.calibration.pivot import board_from_camera_pose
from snreg.camera import StereoCalibration
from snreg.geometry import rotation_distance_deg
from snreg.sources import FrameSource, SourceState
from snreg.workflow.display import DISPLAY_SCALE, display_rgb

MIN_SAMPLE_TURN_DEG = 1.0     # the thesis's arc threshold: a turn smaller than this is not a new sample
MAX_FRAME_RATE_HZ = 30.0      # a source that never blocks (a replay) is read no faster than a camera
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

    @property
    def pose(self) -> np.ndarray:
        """The camera pose (4, 4) the pivot is fitted to."""
        return self.board_from_camera


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


def capture_samples(make_source: Callable[[], FrameSource], imu, calibration: StereoCalibration, board: Board):
    """Generator: a :class:`BoardFrame` per left frame read; returns the source's problem when it ends.

    ``make_source`` is called here, in the worker thread (a renderer or camera may take time to open), and
    the source is closed here when the generator ends or is closed. ``imu.snapshot()`` must give
    ``earth_from_imu`` (3, 3) and ``euler_deg``.
    """
    source = make_source()
    try:
        last_pose = None
        for frame in paced_frames(source):
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
        return source.problem
    finally:
        source.close()


def paced_frames(source: FrameSource):
    """The frames of ``source`` as they come, until it is no longer open (its ``problem`` then says why), each
    handed on no sooner than ``1 / MAX_FRAME_RATE_HZ`` after the one before (what the caller did with it included)."""
    while True:
        began = time.perf_counter()
        frame = source.read()
        if frame is None:
            if source.state is not SourceState.OPEN:
                return
            time.sleep(_WAIT_FOR_FRAME_S)
            continue
        yield frame
        time.sleep(max(0.0, 1.0 / MAX_FRAME_RATE_HZ - (time.perf_counter() - began)))


def _pose(corners: np.ndarray | None, board: Board, calibration: StereoCalibration) -> np.ndarray | None:
    if corners is None:
        return None
    try:
        return board_from_camera_pose(corners, board, calibration.K1, calibration.D1)
    except ValueError:
        return None


def _display(left_bgr: np.ndarray, corners: np.ndarray | None, board: Board) -> np.ndarray:
    """The left frame as shown (:func:`~snreg.workflow.display.display_rgb`), the found corners drawn in (OpenCV's
    row colours)."""
    rgb = display_rgb(left_bgr)
    if corners is not None:
        scaled = (DISPLAY_SCALE * corners).astype(np.float32).reshape(-1, 1, 2)
        cv2.drawChessboardCorners(rgb, board.pattern_size, scaled, True)
    return rgb
