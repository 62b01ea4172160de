"""Scripted motion of the IMU: the ground-truth orientation over time for the simulator and experiments.

A :class:`MotionProfile` is ``world_from_sensor`` as a function of time, built from segments that
hold still or rotate about fixed world axes (z up; at rest and level the accelerometer reads +1 g
on z). A profile is written to and read from a JSON file (:meth:`MotionProfile.to_dict`,
:func:`read_motion_file`): how a program hands its motion to the simulator process
(``snreg imu simulate --motion FILE``).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.files import read_text_file

__all__ = ["Segment", "still", "rotate", "MotionProfile", "protractor_profile", "smooth_progress", "read_motion_file"]


def smooth_progress(u):
    """The share of a smooth move done at ``u`` (0..1) of its time: a raised-cosine rate, zero at both ends like a
    hand move (the peak rate is twice the mean)."""
    u = np.asarray(u, dtype=float)
    return u - np.sin(2 * np.pi * u) / (2 * np.pi)


@dataclass(frozen=True)
class Segment:
    """Rotate by ``angle_deg`` about the fixed world ``axis`` over ``duration_s`` (0 deg: still).
    smooth: raised-cosine rate, zero at both ends like a hand move; else constant rate."""

    duration_s: float
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    angle_deg: float = 0.0
    smooth: bool = True


def still(seconds: float) -> Segment:
    return Segment(float(seconds))


def rotate(axis, angle_deg: float, rate_dps: float, smooth: bool = True) -> Segment:
    """A rotation by ``angle_deg`` at a mean rate of ``rate_dps`` (deg/s) about a world axis."""
    if not rate_dps > 0:
        raise ValueError(f"rotation rate must be positive, got {rate_dps} deg/s")
    return Segment(abs(angle_deg) / rate_dps, tuple(float(a) for a in axis), float(angle_deg), smooth)


class MotionProfile:
    """Ground-truth orientation over time from segments; ``repeat`` loops them (else it holds the end). Before time 0
    the sensor holds the first pose."""

    def __init__(self, segments, initial: Rotation | None = None, repeat: bool = False):
        self.segments = tuple(segments)
        if not self.segments or any(not s.duration_s > 0 for s in self.segments):
            raise ValueError("a motion profile needs segments of positive duration")
        axes = np.array([s.axis for s in self.segments], dtype=float)
        if np.any(np.linalg.norm(axes, axis=1) == 0):
            raise ValueError("a rotation axis must not be zero")
        self._axes = axes / np.linalg.norm(axes, axis=1, keepdims=True)
        self._angles = np.radians([s.angle_deg for s in self.segments])
        self._durations = np.array([s.duration_s for s in self.segments])
        self._smooth = np.array([s.smooth for s in self.segments])
        self._starts = np.concatenate([[0.0], np.cumsum(self._durations)[:-1]])
        self.duration_s = float(self._durations.sum())
        self.initial = initial if initial is not None else Rotation.identity()
        self.repeat = repeat
        steps = Rotation.from_rotvec(self._axes * self._angles[:, None])
        moved = [Rotation.identity()]                 # world rotation from the cycle start to each segment start
        for k in range(len(self.segments)):
            moved.append(steps[k] * moved[-1])
        self._moved = Rotation.concatenate(moved[:-1])
        self._net = moved[-1].as_rotvec()             # one cycle's rotation

    def _locate(self, t_s):
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        cycle = np.maximum(np.floor(t / self.duration_s), 0.0) if self.repeat else np.zeros_like(t)
        tc = np.clip(t - cycle * self.duration_s, 0.0, self.duration_s)
        k = np.clip(np.searchsorted(self._starts, tc, side="right") - 1, 0, len(self.segments) - 1)
        u = np.clip((tc - self._starts[k]) / self._durations[k], 0.0, 1.0)
        return t, cycle, k, u

    def orientation(self, t_s) -> Rotation:
        """``world_from_sensor`` at time(s) ``t_s`` (seconds from the start); one Rotation per time."""
        _, cycle, k, u = self._locate(t_s)
        s = np.where(self._smooth[k], smooth_progress(u), u)
        within = Rotation.from_rotvec(self._axes[k] * (self._angles[k] * s)[:, None])
        return within * self._moved[k] * Rotation.from_rotvec(cycle[:, None] * self._net) * self.initial

    def angular_velocity_dps(self, t_s) -> np.ndarray:
        """(N, 3) angular velocity in the world frame, deg/s."""
        t, _, k, u = self._locate(t_s)
        shape = np.where(self._smooth[k], 1.0 - np.cos(2 * np.pi * u), 1.0)
        moving = (t >= 0) & (self.repeat | (t < self.duration_s))
        rate = np.degrees(self._angles[k]) / self._durations[k] * shape * moving
        return self._axes[k] * rate[:, None]

    def to_dict(self) -> dict:
        """JSON-ready: the segments, the initial orientation (quaternion x, y, z, w) and ``repeat``."""
        return {"segments": [asdict(segment) for segment in self.segments],
                "initial_xyzw": self.initial.as_quat().tolist(), "repeat": self.repeat}

    @classmethod
    def from_dict(cls, data: dict) -> "MotionProfile":
        """Inverse of :meth:`to_dict`; ValueError in one sentence when it is not a profile."""
        try:
            segments = [Segment(float(s["duration_s"]), tuple(float(a) for a in s["axis"]), float(s["angle_deg"]),
                                bool(s["smooth"])) for s in data["segments"]]
            initial = Rotation.from_quat(np.asarray(data["initial_xyzw"], dtype=float))
            repeat = bool(data["repeat"])
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"not a motion profile (segments with duration_s, axis, angle_deg and smooth; "
                             f"initial_xyzw; repeat): {err}") from None
        if any(not np.isfinite([s.duration_s, s.angle_deg, *s.axis]).all() for s in segments):
            raise ValueError("a motion profile's durations, axes and angles must be finite numbers")
        return cls(segments, initial, repeat)


def protractor_profile(angles_deg=(1.0, 5.0, 10.0), axes=((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), rate_dps: float = 5.0,
                       hold_s: float = 2.0, start_s: float = 4.0, repeat: bool = False) -> MotionProfile:
    """The thesis §5.3 protractor moves: still ``start_s`` (the fusion's bias estimate), then per axis
    (horizontal y: tilt; vertical z: yaw) and angle, turn there and back, holding ``hold_s`` after each."""
    segments = [still(start_s)]
    for axis in axes:
        for angle in angles_deg:
            segments += [rotate(axis, angle, rate_dps), still(hold_s), rotate(axis, -angle, rate_dps), still(hold_s)]
    return MotionProfile(segments, repeat=repeat)


def read_motion_file(path) -> MotionProfile:
    """The profile in a JSON file written from :meth:`MotionProfile.to_dict`; ValueError naming the file when it is
    not one."""
    text = read_text_file(path, "motion", ValueError, max_bytes=16 << 20)
    try:
        return MotionProfile.from_dict(json.loads(text))
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not a motion file (JSON: {err.msg} at line {err.lineno})") from None
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
