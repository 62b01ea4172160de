"""The camera's motion from a keyframe to the current pair, from tissue points seen in both: under the pivot model
or free.

Why: the camera turns about the trocar's pivot and slides along its own shaft, so once its rotation is known its
position has one unknown, the insertion ``d`` (docs/design.md, Conventions). With the shaft's direction ``s`` in the camera frame
(:attr:`snreg.chain.ChainCalibration.shaft_camera`) the camera centre lies at ``d R s`` in the trocar frame, so a
point ``P`` of the keyframe's left camera frame (insertion ``d_k``) lies in the current one at::

    Q = A (P + d_k s) - d s          A = current_from_keyframe rotation

(the pivot is at ``-d_k s`` in the keyframe's frame and at ``-d s`` in the current one). :func:`fit_pivot` finds
``A`` and ``d`` from the keyframe's triangulated points and where they are seen now in both eyes, the IMU's ``A``
as a prior (its noise is what the video corrects); :func:`fit_free` finds ``A`` and any translation, so how far the
camera is from where the pivot and the IMU put it (:func:`pivot_departure_mm`) shows a pivot that moved or an IMU
that is off. Both minimise the reprojection error in both eyes (normalised image coordinates, scaled to pixels),
robustly (Huber, then a cut), by Gauss-Newton; the free fit uses the left eye alone (``cv2.solvePnP``): it only
measures the departure.

A fit that fails says so in words (:attr:`MotionFit.failure`) instead of returning whatever its last step left: the
pivot fit when its last phase has not settled within its steps or its system is singular or ill-conditioned (the
insertion not determined by the points: too few, or all too far away to show a slide), the free fit when solvePnP
finds no pose.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

__all__ = ["Observations", "MotionFit", "fit_pivot", "fit_free", "pivot_departure_mm"]

_PHASES = (4.0, 1.0, None)    # Huber thresholds (px): wide (a poor start), narrow; then the inliers alone
_PHASE_STEPS = 4              # Gauss-Newton steps per phase at most
_INLIER_PX = 2.0              # a point whose worse eye is farther than this (at the working scale) is an outlier
# a phase has settled when its last step moved the rotation less than this (rad) and the insertion less than this
# (mm): far below the fit's own errors (0.5 deg prior, tracked insertions to 0.05-0.3 mm); the last phase stops there
# too (issue 36: it went on to steps of 1e-7, a step more in about half the fits for changes under 1e-8 mm)
_SETTLED_RAD, _SETTLED_MM = 1e-4, 1e-3
# the robust phases (Huber) only bring the fit near and pick the inliers, which the last phase then fits to the end:
# they settle at this many times those steps (issue 36: 7 steps a fit to 5 on the bench video's 39 fits, every
# insertion the same to 1e-10 mm and every inlier set the same)
_ROBUST_LOOSER = 30.0
_MAX_CONDITION = 1e10         # a normal matrix less well conditioned than this: the motion is not determined


@dataclass(frozen=True, eq=False)
class Observations:
    """Keyframe points (N, 3) mm in its left camera frame and where they are seen now: normalised coordinates
    (x/z, y/z) in the current left (N, 2) and right (N, 2) camera frames. ``right_from_left`` (4, 4): the stereo
    rig (calibration R, T); ``focal_px``: pixels per normalised unit at the working scale (for robust thresholds)."""

    points: np.ndarray
    left: np.ndarray
    right: np.ndarray
    right_from_left: np.ndarray
    focal_px: float

    def __len__(self) -> int:
        return len(self.points)

    @cached_property
    def seen(self) -> np.ndarray:
        """(N, 2 eyes, 2) where each point is seen, left then right (normalised)."""
        return np.stack([self.left, self.right], axis=1)

    @cached_property
    def eye_rotations(self) -> np.ndarray:
        """(2, 3, 3) each eye's rotation from the left camera frame."""
        return np.stack([np.eye(3), self.right_from_left[:3, :3]])


@dataclass(frozen=True, eq=False)
class MotionFit:
    """``rotation`` (3, 3) current_from_keyframe; ``translation`` (3,) mm of the same; ``insertion_mm``: the pivot
    model's ``d`` (NaN for a free fit); ``inliers`` (N,) bool; ``sd_mm`` the insertion's standard error (NaN for a
    free fit); ``rms_px`` of the inliers at the working scale; ``failure``: why the fit failed, in words ("" when
    it did not; a failed fit's numbers are not a measurement)."""

    rotation: np.ndarray
    translation: np.ndarray
    insertion_mm: float
    inliers: np.ndarray
    sd_mm: float
    rms_px: float
    failure: str = ""

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())


def fit_pivot(obs: Observations, rotation_imu: np.ndarray, shaft: np.ndarray, keyframe_mm: float, guess_mm: float,
              *, rotation_sd_deg: float = 0.5, noise_px: float = 0.3) -> MotionFit:
    """The pivot model's rotation and insertion: ``rotation_imu`` (3, 3) the IMU's current_from_keyframe rotation
    (the prior, sd ``rotation_sd_deg`` per axis against ``noise_px`` per image coordinate), ``shaft`` (3,) unit
    shaft direction in the camera frame, ``keyframe_mm`` the keyframe's insertion, ``guess_mm`` where to start."""
    shaft = np.asarray(shaft, dtype=float)
    rotation_imu = np.asarray(rotation_imu, dtype=float)
    lever = obs.points + keyframe_mm * shaft
    prior_weight = noise_px / np.radians(rotation_sd_deg)     # a rotation of one sd costs as much as noise_px
    rotation, insertion = rotation_imu.copy(), float(guess_mm)
    keep = np.ones(len(obs), bool)
    phase, steps, failure = 0, 0, ""
    while phase < len(_PHASES):
        turned = lever @ rotation.T
        values, d_q, error = _both_eyes(turned - insertion * shaft, obs)
        rows = np.empty((len(turned), 4, 4))
        _turn_rows(turned, d_q, rows[:, :, :3])
        rows[:, :, 3] = (d_q.reshape(-1, 3) @ -shaft).reshape(-1, 4)
        rows = rows.reshape(-1, 4)
        weights, keep = _robust_weights(error, _PHASES[phase])
        tilt = _rotvec(rotation @ rotation_imu.T)
        normal = rows.T @ (rows * weights[:, None])
        gradient = rows.T @ (values * weights)
        normal[:3, :3] += prior_weight**2 * np.eye(3)
        gradient[:3] += prior_weight**2 * tilt
        condition = _condition(normal)
        if not condition < _MAX_CONDITION:
            failure = (f"the motion is not determined by the tissue points (condition number {condition:.1e}: too few "
                       "points, or too far to show a slide)")
            break
        step = -np.linalg.solve(normal, gradient)
        rotation = _rotation(step[:3]) @ rotation
        insertion += step[3]
        steps += 1
        final = phase == len(_PHASES) - 1
        loose = 1.0 if final else _ROBUST_LOOSER
        settled = np.abs(step[:3]).max() < loose * _SETTLED_RAD and abs(step[3]) < loose * _SETTLED_MM
        if settled or steps == _PHASE_STEPS:   # settled: next
            if final and not settled:
                failure = (f"the motion fit did not settle in {_PHASE_STEPS} steps (its last step moved the insertion "
                           f"{abs(step[3]):.3f} mm)")
            phase, steps = phase + 1, 0
    n = int(keep.sum())
    sigma2 = float((values**2 * (weights > 0)).sum()) / max(4 * n - 4, 1)
    sd = float(np.sqrt(np.linalg.inv(normal)[3, 3] * sigma2)) if n and not failure else float("inf")
    translation = keyframe_mm * (rotation @ shaft) - insertion * shaft
    return MotionFit(rotation, translation, insertion, keep, sd, _rms(error, keep), failure)


def fit_free(obs: Observations, rotation: np.ndarray, translation: np.ndarray,
             inliers: np.ndarray | None = None) -> MotionFit:
    """Rotation (3, 3) and translation (3,) mm current_from_keyframe with no model of the motion, from a start: the
    left eye's view of the keyframe's points (``cv2.solvePnP``), the ``inliers`` (N,) alone when given. When solvePnP
    fails the fit says so (``failure``) and keeps the start."""
    use = np.ones(len(obs), bool) if inliers is None else np.asarray(inliers, bool)
    rvec, tvec = _rotvec(np.asarray(rotation, float)).reshape(3, 1), np.asarray(translation, float).reshape(3, 1)
    try:
        ok, rvec, tvec = cv2.solvePnP(obs.points[use].reshape(-1, 1, 3), obs.left[use].reshape(-1, 1, 2), np.eye(3),
                                      None, rvec, tvec, useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE)
    except cv2.error:          # too few points for it, or a degenerate set
        ok = False
    if not ok or not (np.all(np.isfinite(rvec)) and np.all(np.isfinite(tvec))):
        nan = float("nan")
        return MotionFit(np.asarray(rotation, float), np.asarray(translation, float), nan, np.zeros(len(obs), bool),
                         nan, float("inf"), f"solvePnP found no camera pose from {int(use.sum())} tissue points")
    rotation, translation = _rotation(rvec.ravel()), tvec.ravel()
    q = obs.points @ rotation.T + translation
    error = obs.focal_px * np.hypot(q[:, 0] / q[:, 2] - obs.left[:, 0], q[:, 1] / q[:, 2] - obs.left[:, 1])
    return MotionFit(rotation, translation, float("nan"), use & (error < _INLIER_PX), float("nan"), _rms(error, use))


def pivot_departure_mm(free: MotionFit, rotation_imu: np.ndarray, shaft: np.ndarray, keyframe_mm: float) -> float:
    """How far (mm) the freely fitted camera centre lies from the shaft line where the pivot and the IMU's rotation
    (3, 3, current_from_keyframe) put it, whatever the insertion: 0 for a camera that turned about the pivot as the
    IMU says and slid along its shaft."""
    shaft = np.asarray(shaft, dtype=float)
    # a pivot-model translation is keyframe_mm * A s - d s for some d; the part of the free one off that line
    offset = keyframe_mm * (np.asarray(rotation_imu, float) @ shaft) - free.translation
    return float(np.linalg.norm(offset - (offset @ shaft) * shaft))


def _both_eyes(q: np.ndarray, obs: Observations):
    """Reprojection residuals (4N,) px of points ``q`` (N, 3, the current left camera frame) in both eyes, their
    derivatives with respect to ``q`` (N, 4, 3), and each point's worse eye (N,). Row order per point: left x, left
    y, right x, right y. Both eyes in one pass of array operations: this runs a few hundred times a second, and on
    a fit's hundred or two points each numpy call costs more than its arithmetic."""
    eyes = np.empty((len(q), 2, 3))
    eyes[:, 0] = q
    np.matmul(q, obs.right_from_left[:3, :3].T, out=eyes[:, 1])
    eyes[:, 1] += obs.right_from_left[:3, 3]
    inverse_z = 1.0 / eyes[:, :, 2:]
    xy = eyes[:, :, :2] * inverse_z
    values = obs.focal_px * (xy - obs.seen)                                          # (N, 2 eyes, 2)
    # d(f x/z)/dq = f/z (row 0 - x row 2) of the eye's rotation from the left camera, and so for y
    rotations = obs.eye_rotations
    d_q = (obs.focal_px * inverse_z)[:, :, :, None] * (rotations[:, :2] - xy[:, :, :, None] * rotations[:, 2:3])
    squared = values * values
    error = np.sqrt(np.maximum(squared[:, 0, 0] + squared[:, 0, 1], squared[:, 1, 0] + squared[:, 1, 1]))
    return values.reshape(-1), d_q.reshape(-1, 4, 3), error


def _turn_rows(turned: np.ndarray, d_q: np.ndarray, rows: np.ndarray) -> None:
    """Write into ``rows`` (N, 4, 3) the derivatives of the residuals with respect to a small rotation vector ``w``
    turning the points (``turned`` (N, 3) -> turned + w x turned), from theirs with respect to the points (``d_q``,
    N, 4, 3): for a row ``a``, a . (w x v) = w . (v x a). Element by element: numpy's stacked 3 x 3 products cost
    several times more on a fit's few hundred points."""
    v0, v1, v2 = (turned[:, None, k] for k in range(3))
    a0, a1, a2 = (d_q[:, :, k] for k in range(3))
    np.subtract(v1 * a2, v2 * a1, out=rows[:, :, 0])
    np.subtract(v2 * a0, v0 * a2, out=rows[:, :, 1])
    np.subtract(v0 * a1, v1 * a0, out=rows[:, :, 2])


def _robust_weights(error: np.ndarray, huber_px: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Per-row weights (Huber at ``huber_px``; None: the inliers alone) and the inliers."""
    keep = error < _INLIER_PX
    if huber_px is None:
        point = keep.astype(float)
    else:
        point = np.minimum(1.0, huber_px / np.maximum(error, 1e-9))
    return np.repeat(point, 4), keep


def _condition(normal: np.ndarray) -> float:
    """The condition number of a symmetric positive semi-definite matrix (its largest eigenvalue over its smallest;
    infinite when singular): ``np.linalg.cond``'s value for such a matrix, without a singular value decomposition."""
    values = np.linalg.eigvalsh(normal)
    return float(values[-1] / values[0]) if values[0] > 0 else float("inf")


def _rms(error: np.ndarray, keep: np.ndarray) -> float:
    return float(np.sqrt((error[keep] ** 2).mean() / 2.0)) if keep.any() else float("inf")


def _rotation(rotvec: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rotvec, np.float64).reshape(3, 1))[0]


def _rotvec(rotation: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(rotation, np.float64))[0].ravel()
