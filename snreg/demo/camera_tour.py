"""The surgery demo's camera over one tour of the nodes: resting while the probe rests on a node, sliding through the
trocar and turning about the pivot between rests; frame by frame for the renderer and as a motion profile for the
simulated IMU, from one timeline.

Why: ``snreg demo --camera surgery`` must show a camera that moves as a surgeon moves it (issue 27) while the
rendered frames and the IMU's samples agree at every instant, as a real camera and IMU on one endoscope do. The tour
is a list of rests (:class:`CameraKey`: the slide from the start insertion and the shaft's turn) with the keys the
camera passes through on its way to the next; each leg from key to key is one smooth move (the raised-cosine rate of
:func:`~snreg.demo.imu_motion.smooth_progress`, zero at both ends), as long as it must be for its fastest instant to
stay within ``step_mm`` and ``step_deg`` per frame. The shaft turns about an axis across it (no roll about itself),
so along a leg the camera turns about one fixed axis: one segment of a :class:`~snreg.demo.imu_motion.MotionProfile`,
which is what the IMU simulator plays (:meth:`CameraTour.motion_profile`).

Frames: rest ``n`` holds ``rest_frames`` frames; the move after it starts at the rest's last frame and ends where the
next rest's first frame is (its frames lie strictly between), and the tour repeats (the last move returns to the
first rest, the start pose).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.chain import ChainCalibration
from snreg.demo.camera_path import CameraPath
from snreg.demo.imu_motion import MotionProfile, Segment, smooth_progress

__all__ = ["CameraKey", "CameraTour"]


@dataclass(frozen=True)
class CameraKey:
    """A camera pose on the trocar: ``slide_mm`` deeper than the start insertion (negative: drawn back) and the shaft
    turned about the pivot by ``turn_deg`` (about the trocar's x axis, then its y axis, as one rotation vector: the view
    turns up for x > 0, right for y > 0)."""

    slide_mm: float = 0.0
    turn_deg: tuple[float, float] = (0.0, 0.0)

    @property
    def turn(self) -> Rotation:
        return Rotation.from_rotvec(np.radians([self.turn_deg[0], self.turn_deg[1], 0.0]))


@dataclass(frozen=True)
class _Leg:
    """One smooth move from ``start`` (a key) to ``end`` over ``frames`` frame periods, beginning at frame ``first``."""

    first: float
    frames: int
    start: CameraKey
    end: CameraKey


class CameraTour:
    """The camera over a tour: ``rests`` (one key per node, the first the start pose), ``via[n]`` the keys passed on
    the way from rest ``n`` to the next; ``rest_frames`` per rest; ``start_mm`` the insertion of the start pose;
    ``min_move_frames`` at least per move (the probe's glide); ``step_mm`` and ``step_deg`` the most the camera
    slides and turns from one frame to the next."""

    def __init__(self, rests: Sequence[CameraKey], via: Sequence[Sequence[CameraKey]], *, rest_frames: int,
                 start_mm: float, min_move_frames: int = 5, step_mm: float = 2.5, step_deg: float = 1.5):
        if len(via) != len(rests) or rest_frames < 2:
            raise ValueError("a tour needs the keys passed after each rest and at least 2 frames per rest")
        self.rests, self.start_mm, self.rest_frames = tuple(rests), float(start_mm), int(rest_frames)
        self.rest_starts: list[int] = []      # first frame of each rest
        self.move_frames: list[int] = []      # frames strictly between each rest and the next
        self.legs: list[_Leg] = []
        first = 0
        for n, rest in enumerate(self.rests):
            self.rest_starts.append(first)
            keys = [rest, *via[n], self.rests[(n + 1) % len(self.rests)]]
            lengths = [_leg_frames(a, b, step_mm, step_deg) for a, b in zip(keys, keys[1:])]
            lengths[-1] += max(0, min_move_frames + 1 - sum(lengths))
            leg_first = first + self.rest_frames - 1
            for a, b, length in zip(keys, keys[1:], lengths):
                self.legs.append(_Leg(leg_first, length, a, b))
                leg_first += length
            self.move_frames.append(sum(lengths) - 1)
            first += self.rest_frames + self.move_frames[-1]
        self.cycle = first

    def resting(self, index: int) -> int | None:
        """The rest (node) the camera holds at frame ``index``, None while it moves."""
        within = index % self.cycle
        for n, first in enumerate(self.rest_starts):
            if first <= within < first + self.rest_frames:
                return n
        return None

    def move_progress(self, index: int) -> tuple[int, float]:
        """At frame ``index``: the rest last left (or held) and how far (0..1, in frames) the move from it to the
        next has gone (0 while resting)."""
        within = index % self.cycle
        n = max(k for k, first in enumerate(self.rest_starts) if first <= within)
        done = within - (self.rest_starts[n] + self.rest_frames - 1)
        return n, max(0.0, done / (self.move_frames[n] + 1))

    def key_at(self, index: int) -> tuple[float, Rotation]:
        """(insertion mm, the shaft's turn) at frame ``index``."""
        within = float(index % self.cycle)
        for leg in self.legs:
            if leg.first <= within < leg.first + leg.frames:
                s = float(smooth_progress((within - leg.first) / leg.frames))
                step = leg.end.turn * leg.start.turn.inv()
                turn = Rotation.from_rotvec(s * step.as_rotvec()) * leg.start.turn
                return self.start_mm + leg.start.slide_mm + s * (leg.end.slide_mm - leg.start.slide_mm), turn
        rest = self.rests[self.resting(index)]
        return self.start_mm + rest.slide_mm, rest.turn

    def path(self) -> CameraPath:
        """One tour's poses, frame by frame (:class:`~snreg.demo.camera_path.CameraPath`: no roll)."""
        keys = [self.key_at(k) for k in range(self.cycle)]
        return CameraPath(np.array([d for d, _ in keys]), Rotation.concatenate([t for _, t in keys]),
                          np.zeros(self.cycle))

    def motion_profile(self, chain: ChainCalibration, fps: float) -> MotionProfile:
        """The IMU's orientation over the tour on ``chain`` (``earth_from_imu``; time 0 at frame 0, ``fps`` frames a
        second), repeating: what the simulated IMU plays."""
        earth_from_trocar = Rotation.from_matrix(chain.trocar_from_earth[:3, :3]).inv()
        segments, at = [], 0.0
        for leg in self.legs:
            if leg.first > at:
                segments.append(Segment((leg.first - at) / fps))
            step = earth_from_trocar * leg.end.turn * leg.start.turn.inv() * earth_from_trocar.inv()
            angle = float(np.degrees(step.magnitude()))
            axis = tuple(step.as_rotvec() / np.radians(angle)) if angle > 0 else (0.0, 0.0, 1.0)
            segments.append(Segment(leg.frames / fps, axis, angle, smooth=True))
            at = leg.first + leg.frames
        if self.cycle > at:
            segments.append(Segment((self.cycle - at) / fps))
        first = CameraPath(np.array([self.start_mm + self.rests[0].slide_mm]),
                           Rotation.concatenate([self.rests[0].turn]), np.zeros(1))
        return MotionProfile(segments, Rotation.from_matrix(first.earth_from_imu(0, chain)), repeat=True)


def _leg_frames(a: CameraKey, b: CameraKey, step_mm: float, step_deg: float) -> int:
    """Frame periods a smooth move from ``a`` to ``b`` needs so that its fastest frame (twice the mean) stays within
    ``step_mm`` and ``step_deg``."""
    angle = float(np.degrees((b.turn * a.turn.inv()).magnitude()))
    return max(1, int(np.ceil(2.0 * max(abs(b.slide_mm - a.slide_mm) / step_mm, angle / step_deg))))
