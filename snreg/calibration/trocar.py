"""The thesis's trocar distances (§3.5.1, §4.1): the arc method (eq. 14), the known-spot method (eq. 15), manual entry.

Each returns a :class:`DistanceEstimate`: the median of per-sample estimates with its interquartile
range, as the thesis reports them (IMU-trocar 452 mm [416, 488], trocar-camera 158 mm [157, 158];
the manual IMU-trocar measurement, 460 mm, was used). :mod:`snreg.calibration.pivot` measures the
trocar-camera distance better, from camera poses, and :mod:`snreg.chain` shows why the IMU-trocar
distance hardly matters.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.geometry import rotation_distance_deg

__all__ = ["DistanceEstimate", "arc_distance", "known_spot_distance", "manual_distance"]


@dataclass(frozen=True, eq=False)
class DistanceEstimate:
    """A distance, mm: the median ``distance_mm`` of the per-sample ``values_mm`` (n_used,), their
    quartiles ``q25_mm``, ``q75_mm``, and the ``method`` ("arc", "known-spot" or "manual")."""

    distance_mm: float
    q25_mm: float
    q75_mm: float
    values_mm: np.ndarray
    method: str

    @property
    def iqr_mm(self) -> float:
        """Interquartile range, mm: the spread the thesis reports."""
        return self.q75_mm - self.q25_mm

    @property
    def n_used(self) -> int:
        return len(self.values_mm)


def arc_distance(positions_mm: np.ndarray, orientations, *, min_move_mm: float = 1.0,
                 min_angle_deg: float = 1.0) -> DistanceEstimate:
    """Distance from the pivot to a point on the shaft that swings about it (thesis eq. 14, Fig 8A, 9).

    ``positions_mm`` (N, 3): the point (the IMU, by double integration in the thesis; or the camera,
    from any tracker) at N samples in a fixed frame; ``orientations``: (N, 3, 3) or a scipy
    ``Rotation`` of length N, the shaft's orientation at each (e.g. ``earth_from_imu``; from Euler
    angles by :func:`snreg.geometry.rotation_from_euler`). For consecutive samples the chord ``l``
    and the turn ``T`` (eq. 5) give ``0.5 l / sin(0.5 T)`` (eq. 14); only pairs that moved more than
    ``min_move_mm`` and turned more than ``min_angle_deg`` count (thesis: 1 mm, 1 degree).
    Eq. 14 assumes the turn is a swing about the pivot: a roll about the shaft turns without moving
    the point, which biases the estimate low.
    """
    positions = np.asarray(positions_mm, dtype=float)
    rotations = orientations.as_matrix() if isinstance(orientations, Rotation) else np.asarray(orientations, dtype=float)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise ValueError(f"positions must have shape (N, 3) mm, got {positions.shape}")
    if rotations.shape != (len(positions), 3, 3):
        raise ValueError(f"{len(positions)} positions need {len(positions)} orientations of shape (3, 3), "
                         f"got shape {rotations.shape}")
    if len(positions) < 2:
        raise ValueError("the arc method needs at least two samples")
    chord = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    turn = rotation_distance_deg(rotations[1:], rotations[:-1])
    keep = (chord > min_move_mm) & (turn > min_angle_deg)
    if not keep.any():
        raise ValueError(f"no two consecutive samples moved more than {min_move_mm:g} mm and turned more than "
                         f"{min_angle_deg:g} degrees; swing the endoscope about the trocar while recording")
    return _estimate(0.5 * chord[keep] / np.sin(np.radians(0.5 * turn[keep])), "arc")


def known_spot_distance(spots_camera_mm: np.ndarray, trocar_spot_mm) -> DistanceEstimate:
    """Trocar-camera distance from spots at known distances from the trocar, seen by the camera (thesis eq. 15, Fig 8A, 10).

    ``spots_camera_mm`` (N, 3): a spot S in the camera frame at each sample; ``trocar_spot_mm``: the
    known trocar-S distance D, mm, one for all or (N,). With the pivot on the camera's axis at
    ``(0, 0, -d)`` and D the straight trocar-S distance, ``D^2 = S_xy^2 + (S_z + d)^2``, so
    ``d = sqrt(D^2 - S_xy^2) - S_z``. The thesis prints ``+ S_xy^2`` under the root, which does not
    fit that geometry (it overestimates d by about ``S_xy^2 / D``); this is the geometric form.
    Samples with ``S_xy > D`` (impossible geometry) are left out.
    """
    spots = np.asarray(spots_camera_mm, dtype=float)
    if spots.ndim != 2 or spots.shape[1] != 3:
        raise ValueError(f"spots must have shape (N, 3) mm, got {spots.shape}")
    known = np.asarray(trocar_spot_mm, dtype=float)
    if known.ndim > 1 or (known.ndim == 1 and len(known) != len(spots)):
        raise ValueError(f"give one known trocar-spot distance or one per spot ({len(spots)}), got shape {known.shape}")
    if len(spots) == 0:
        raise ValueError("the known-spot method needs at least one spot")
    if not (np.isfinite(known).all() and np.all(known > 0)):
        raise ValueError("the known trocar-spot distance must be positive (mm)")
    known = np.broadcast_to(known, (len(spots),))
    lateral_sq = np.sum(spots[:, :2] ** 2, axis=1)
    keep = np.isfinite(spots).all(axis=1) & (lateral_sq <= known ** 2)
    if not keep.any():
        raise ValueError("no spot is nearer the camera axis than its known distance from the trocar; "
                         "check the distance (mm) and that the spots are in the camera frame")
    return _estimate(np.sqrt(known[keep] ** 2 - lateral_sq[keep]) - spots[keep, 2], "known-spot")


def manual_distance(distance_mm: float) -> DistanceEstimate:
    """A distance measured by hand, mm (thesis §4.1: IMU-trocar 460 mm), as an estimate without spread."""
    if not (np.isfinite(distance_mm) and distance_mm > 0):
        raise ValueError(f"a measured distance must be positive (mm), got {distance_mm}")
    return _estimate(np.array([float(distance_mm)]), "manual")


def _estimate(values: np.ndarray, method: str) -> DistanceEstimate:
    q25, median, q75 = np.percentile(values, [25, 50, 75])
    return DistanceEstimate(float(median), float(q25), float(q75), values, method)
