"""A live stereo feed of a checkerboard moving through varied poses: the calibration wizard without a camera.

Why: the calibration wizard's demo and tests need a video-rate feed with a known truth. A
:class:`BoardTour` holds the board at each of ``n_poses`` seeded poses
(:func:`~snreg.demo.board_render.random_board_poses`) for ``dwell_frames`` frames, then glides
to the next over ``move_frames`` frames (rotation slerped, centre moved on a straight line), and
repeats. Every distinct pose is rendered once with
:func:`~snreg.demo.board_render.render_stereo_board` (first use or :meth:`BoardTour.prerender`)
and replayed from memory, so the feed then costs only a colour conversion per frame; the cameras are
a reduced-resolution calibration (default: thesis Appendix A at half size) to keep rendering cheap.
Sources made by one tour share its renders.

>>> calibration = thesis_calibration().scaled(0.5)
>>> source = board_feed(calibration, Board(10, 7, 10.0), n_poses=20, seed=3)
>>> frame = source.read()          # StereoFrame, 960x540 BGR; the truth is ``calibration``
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from snreg.calibration.checkerboard import THESIS_BOARD, Board
from snreg.camera import StereoCalibration, thesis_calibration
from snreg.demo.board_render import random_board_poses, render_stereo_board
from snreg.sources import CallableSource

__all__ = ["BoardSchedule", "BoardTour", "board_feed"]

_DISTANCE_MM = (110.0, 250.0)              # near enough that the squares stay over ~10 px in half-size detection


@dataclass(frozen=True)
class BoardSchedule:
    """Frames the board rests at each pose, and frames it takes to move to the next."""

    dwell_frames: int = 20
    move_frames: int = 2

    def __post_init__(self):
        if self.dwell_frames < 1 or self.move_frames < 0:
            raise ValueError(f"dwell_frames must be >= 1 and move_frames >= 0, got {self.dwell_frames}, {self.move_frames}")

    @property
    def period(self) -> int:
        """Frames from arriving at one pose to arriving at the next."""
        return self.dwell_frames + self.move_frames


class BoardTour:
    """The board's tour in front of ``calibration``'s cameras: poses, truth per frame, cached renders."""

    def __init__(self, calibration: StereoCalibration | None = None, board: Board = THESIS_BOARD, *, n_poses: int = 20,
                 schedule: BoardSchedule = BoardSchedule(), noise_sigma: float = 1.5, seed: int = 0):
        self.calibration = calibration if calibration is not None else thesis_calibration().scaled(0.5)
        self.board, self.schedule, self.noise_sigma, self.seed = board, schedule, noise_sigma, seed
        self.poses = random_board_poses(self.calibration, board, n_poses, seed, distance_mm=_DISTANCE_MM)
        self._centre = np.array([(board.cols - 1) / 2.0 * board.square_mm, (board.rows - 1) / 2.0 * board.square_mm, 0.0, 1.0])
        self._renders: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    @property
    def n_frames(self) -> int:
        """Frames in one tour (the feed repeats after them)."""
        return len(self.poses) * self.schedule.period

    def pose_at(self, index: int) -> tuple[int, int]:
        """``(pose, step)`` at frame ``index``: the pose last arrived at and the frames since
        (``step >= dwell_frames`` while moving on to the next pose)."""
        return divmod(index % self.n_frames, self.schedule.period)

    def camera_from_board(self, index: int) -> np.ndarray:
        """(4, 4) true board pose in the left camera frame at frame ``index``, mm."""
        pose, step = self.pose_at(index)
        here = self.poses[pose]
        if step < self.schedule.dwell_frames:
            return here
        there = self.poses[(pose + 1) % len(self.poses)]
        u = (step - self.schedule.dwell_frames + 1) / (self.schedule.move_frames + 1)
        rotation = Slerp([0.0, 1.0], Rotation.from_matrix([here[:3, :3], there[:3, :3]]))([u]).as_matrix()[0]
        centre_here, centre_there = (here @ self._centre)[:3], (there @ self._centre)[:3]
        out = np.eye(4)
        out[:3, :3] = rotation
        out[:3, 3] = centre_here + u * (centre_there - centre_here) - rotation @ self._centre[:3]
        return out

    def render(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right BGR frames at frame ``index`` (a ``CallableSource`` callback); all dwell frames of a
        pose share one exposure."""
        pose, step = self.pose_at(index)
        key = (pose, 0 if step < self.schedule.dwell_frames else step)
        if key not in self._renders:
            self._renders[key] = render_stereo_board(self.calibration, self.board, self.camera_from_board(index),
                                                     noise_sigma=self.noise_sigma,
                                                     seed=self.seed + 1 + pose * self.schedule.period + key[1])
        left, right = self._renders[key]
        return cv2.cvtColor(left, cv2.COLOR_GRAY2BGR), cv2.cvtColor(right, cv2.COLOR_GRAY2BGR)

    def prerender(self) -> None:
        """Render the whole tour now (about 0.1 s per distinct pose at half size), so the feed only replays."""
        for index in range(self.n_frames):
            self.render(index)

    def source(self, fps: float = 30.0) -> CallableSource:
        """A new endless source of this tour from frame 0 (sharing the renders)."""
        return CallableSource(self.render, fps, name="Rendered checkerboard feed")


def board_feed(calibration: StereoCalibration | None = None, board: Board = THESIS_BOARD, *, n_poses: int = 20,
               schedule: BoardSchedule = BoardSchedule(), noise_sigma: float = 1.5, fps: float = 30.0,
               seed: int = 0) -> CallableSource:
    """An endless :class:`~snreg.sources.CallableSource` of BGR stereo frames of ``board`` touring ``n_poses`` poses.

    ``calibration`` (default: thesis Appendix A at half size) is both the cameras rendered and the truth a
    calibration should recover. Poses and sensor noise (``noise_sigma`` grey levels) follow ``seed``.
    Renders happen on first use; for the truth per frame or a pre-rendered feed use :class:`BoardTour`.
    """
    return BoardTour(calibration, board, n_poses=n_poses, schedule=schedule, noise_sigma=noise_sigma, seed=seed).source(fps)
