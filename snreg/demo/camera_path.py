"""The camera's true motion in surgery: sliding through the trocar and turning about the pivot, one pose per pair.

Why: the insertion tracker, its experiment and the surgery demo need a camera that moves as a surgeon moves it
(issue 27): slides of centimetres and turns of tens of degrees, with rests between, at most a few mm and degrees
between consecutive pairs (pairs sub-sampled in time), optionally back to where it started. The shaft turns about
the pivot without rolling, and the camera rolls about its own axis a little (the 30-degree scope is turned by
hand). Poses follow docs/design.md, Conventions: ``trocar_from_camera`` with the camera centre at ``d R s`` for the insertion
``d``, the rotation ``R`` and the shaft's direction ``s`` in the camera frame (:class:`~snreg.chain.ChainCalibration`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from snreg.chain import ChainCalibration, reference_rotation
from snreg.geometry import make_transform

__all__ = ["CameraPath", "surgery_path", "still_path"]


@dataclass(frozen=True, eq=False)
class CameraPath:
    """Per pair: the insertion (n,) mm and the shaft's turn from the reference pose (a scipy Rotation of n, trocar
    frame, about the pivot), with the camera's roll about the shaft (n,) degrees."""

    insertion_mm: np.ndarray
    turns: Rotation
    roll_deg: np.ndarray

    def __len__(self) -> int:
        return len(self.insertion_mm)

    def trocar_from_camera(self, index: int, chain: ChainCalibration) -> np.ndarray:
        """(4, 4) the camera's true pose at pair ``index`` in the trocar frame of ``chain``'s shaft."""
        shaft = chain.shaft_camera
        roll = Rotation.from_rotvec(np.radians(self.roll_deg[index]) * shaft).as_matrix()
        rotation = self.turns[index].as_matrix() @ reference_rotation(shaft) @ roll
        return make_transform(rotation, self.insertion_mm[index] * (rotation @ shaft))

    def earth_from_imu(self, index: int, chain: ChainCalibration) -> np.ndarray:
        """(3, 3) the IMU's true orientation at pair ``index`` (as an AHRS gives it) for ``chain``."""
        rotation = self.trocar_from_camera(index, chain)[:3, :3]
        return chain.trocar_from_earth[:3, :3].T @ rotation @ chain.imu_from_camera[:3, :3].T


def still_path(n_pairs: int, start_mm: float) -> CameraPath:
    """The thesis' camera: never moving."""
    return CameraPath(np.full(n_pairs, float(start_mm)), Rotation.identity(n_pairs), np.zeros(n_pairs))


def surgery_path(n_pairs: int, start_mm: float, *, slide_mm: float = 40.0, turn_deg: float = 30.0,
                 roll_deg: float = 10.0, step_mm: float = 5.0, step_deg: float = 3.0, rest_pairs: tuple[int, int] = (1, 5),
                 back_to_start: bool = True, seed: int = 0) -> CameraPath:
    """About ``n_pairs`` poses: from the reference pose at ``start_mm`` to random targets (insertion within
    ``+-slide_mm``, shaft turned up to ``turn_deg``, rolled up to ``roll_deg``) at up to ``step_mm`` and ``step_deg``
    per pair, resting ``rest_pairs`` pairs at each; with ``back_to_start`` the last moves return to the start
    pose and rest there (the path may end a few pairs past ``n_pairs`` to get there)."""
    rng = np.random.default_rng([seed, 27])
    d, turn, roll = [float(start_mm)], [np.zeros(3)], [0.0]

    def go(target_d: float, target_turn: np.ndarray, target_roll: float) -> None:
        start = Rotation.from_rotvec(turn[-1])
        end = Rotation.from_rotvec(target_turn)
        angle = np.degrees((end * start.inv()).magnitude()) + abs(target_roll - roll[-1])
        pace = rng.uniform(0.4, 1.0)
        steps = max(1, int(np.ceil(max(abs(target_d - d[-1]) / (pace * step_mm), angle / (pace * step_deg)))))
        turns = Slerp([0.0, 1.0], Rotation.concatenate([start, end]))(np.arange(1, steps + 1) / steps)
        for k in range(steps):
            d.append(d[-1] + (target_d - d[-1]) / (steps - k))
            turn.append(turns[k].as_rotvec())
            roll.append(roll[-1] + (target_roll - roll[-1]) / (steps - k))
        for _ in range(int(rng.integers(rest_pairs[0], rest_pairs[1] + 1))):
            d.append(d[-1])
            turn.append(turn[-1])
            roll.append(roll[-1])

    home = (float(start_mm), np.zeros(3), 0.0)
    while len(d) < n_pairs * (0.8 if back_to_start else 1.0):
        heading = rng.uniform(0.0, 2.0 * np.pi)
        tilt = np.radians(turn_deg) * np.sqrt(rng.uniform(0.0, 1.0))
        go(start_mm + rng.uniform(-slide_mm, slide_mm), tilt * np.array([np.cos(heading), np.sin(heading), 0.0]),
           rng.uniform(-roll_deg, roll_deg))
    if back_to_start:
        go(*home)
    return CameraPath(np.array(d), Rotation.from_rotvec(np.array(turn)), np.array(roll))
