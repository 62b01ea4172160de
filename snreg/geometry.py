"""Rigid transforms, Euler angles and rotation distances (thesis §2.1, eq. 1-6).

A transform is a 4x4 homogeneous array named ``<to>_from_<from>``:
``p_trocar = trocar_from_camera @ p_camera``. Angles are degrees at this
interface; scipy's ``Rotation`` does the work inside.

Euler convention (docs/design.md, Conventions): yaw about z, pitch about y, roll about x,
``R = Rz @ Ry @ Rx`` (thesis eq. 4; its eq. 1 and 3 swap the Rx/Rz labels).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "make_transform",
    "invert",
    "apply",
    "rotation_from_euler",
    "euler_from_rotation",
    "transform_from_euler",
    "rotation_angle_deg",
    "rotation_distance_deg",
    "kabsch",
]


def make_transform(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """Build 4x4 transforms from rotations (..., 3, 3) and translations (..., 3)."""
    rotation = np.asarray(rotation, dtype=float)
    translation = np.asarray(translation, dtype=float)
    shape = np.broadcast_shapes(rotation.shape[:-2], translation.shape[:-1])
    out = np.zeros(shape + (4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def invert(transform: np.ndarray) -> np.ndarray:
    """Invert rigid 4x4 transform(s) (..., 4, 4): ``a_from_b`` -> ``b_from_a``."""
    transform = np.asarray(transform, dtype=float)
    rot_t = np.swapaxes(transform[..., :3, :3], -1, -2)
    return make_transform(rot_t, -np.einsum("...ij,...j->...i", rot_t, transform[..., :3, 3]))


def apply(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map points (N, 3) through a 4x4 transform; returns (N, 3)."""
    transform = np.asarray(transform, dtype=float)
    points = np.asarray(points, dtype=float)
    return points @ transform[:3, :3].T + transform[:3, 3]


def rotation_from_euler(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Rotation matrix ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``, angles in degrees (thesis eq. 1-4)."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()


def euler_from_rotation(rotation: np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, roll) in degrees of a rotation matrix; inverse of :func:`rotation_from_euler`."""
    yaw, pitch, roll = Rotation.from_matrix(np.asarray(rotation)[:3, :3]).as_euler("ZYX", degrees=True)
    return float(yaw), float(pitch), float(roll)


def transform_from_euler(yaw: float, pitch: float, roll: float, translation=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 transform from Euler angles (degrees) and a translation (mm)."""
    return make_transform(rotation_from_euler(yaw, pitch, roll), np.asarray(translation, dtype=float))


def rotation_angle_deg(rotation: np.ndarray) -> np.ndarray:
    """Angle of rotation(s) (..., 3, 3) or of the rotation part of (..., 4, 4), in degrees."""
    rotation = np.asarray(rotation, dtype=float)[..., :3, :3]
    cos = (np.trace(rotation, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def rotation_distance_deg(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Angle between rotations P and Q, ``acos((trace(P Q^-1) - 1) / 2)`` (thesis eq. 5), degrees."""
    p = np.asarray(p, dtype=float)[..., :3, :3]
    q = np.asarray(q, dtype=float)[..., :3, :3]
    return rotation_angle_deg(p @ np.swapaxes(q, -1, -2))


def kabsch(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Least-squares rigid transform(s) mapping ``source`` onto ``target`` (Kabsch/Umeyama, no scale).

    source, target: (..., K, 3) paired points; weights: (..., K) or None.
    Returns (..., 4, 4) ``target_from_source``. Batched over leading axes, which the
    global registration needs (thousands of triplet hypotheses at once) and which
    scipy's ``Rotation.align_vectors`` does not offer.
    """
    source = np.asarray(source, dtype=float)
    target = np.asarray(target, dtype=float)
    if weights is None and source.ndim == 2:
        return _kabsch_one(source, target)
    if weights is None:
        weights = np.ones(source.shape[:-1])
    weights = np.asarray(weights, dtype=float)
    wsum = weights.sum(axis=-1, keepdims=True)
    src_c = (weights[..., None] * source).sum(axis=-2) / wsum
    dst_c = (weights[..., None] * target).sum(axis=-2) / wsum
    src0 = source - src_c[..., None, :]
    dst0 = target - dst_c[..., None, :]
    cov = np.einsum("...k,...ki,...kj->...ij", weights, dst0, src0)
    u, _, vt = np.linalg.svd(cov)
    det = np.linalg.det(u @ vt)
    d = np.ones(det.shape + (3,))
    d[..., 2] = np.sign(det) + (det == 0)
    rotation = (u * d[..., None, :]) @ vt
    translation = dst_c - np.einsum("...ij,...j->...i", rotation, src_c)
    return make_transform(rotation, translation)


def _kabsch_one(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Unweighted, unbatched :func:`kabsch`: the inner loop of every refinement, kept lean."""
    src_c, dst_c = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((target - dst_c).T @ (source - src_c))
    rotation = u @ vt
    if np.linalg.det(rotation) < 0:
        u[:, 2] = -u[:, 2]
        rotation = u @ vt
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = dst_c - rotation @ src_c
    return out
