"""The least-squares rigid correction of paired nodes that stays within the registration's bounds.

Why: a noisy fit of a few pairs can lean past the rotation or translation bound while the truth lies inside it; the
best fit inside the bounds is then the answer (with its honest, lower score), not a refusal (docs/design.md, Bounds).

How: with the translation fixed, the best rotation maximises trace(R^T M) for the pairs' cross-covariance M. Inside
the angle bound that is Kabsch; on it, Rodrigues' formula for R = rotation by the bound angle about a unit axis n
turns the objective into a linear plus quadratic form in n on the unit sphere (a trust-region subproblem, solved
exactly through its secular equation). The translation, given the rotation, is the centroid match pulled back onto
the translation bound (the residual is isotropic in it). The two steps alternate a few times.
"""

from __future__ import annotations

import numpy as np

from snreg import geometry
from snreg.registration._problem import Problem

__all__ = ["fit_within_bounds", "tilted_within"]

_ALTERNATIONS = 6


def _best_rotation(m: np.ndarray, theta: float) -> np.ndarray:
    """The rotation (3, 3) of angle <= ``theta`` (radians) maximising trace(R^T m)."""
    u, _, vt = np.linalg.svd(m)
    free = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0]) @ vt
    if geometry.rotation_angle_deg(free) <= np.degrees(theta):
        return free
    # on the bound: maximise sin(theta) n.w + (1 - cos(theta)) n^T S n over unit n
    w = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]) * np.sin(theta)
    eigen, basis = np.linalg.eigh(0.5 * (m + m.T) * (1.0 - np.cos(theta)))
    g = basis.T @ w / 2.0                                   # stationarity: (mu - S) n = w / 2
    top = eigen[-1]
    if np.linalg.norm(g) < 1e-12:
        axis = basis[:, -1]
    else:
        low, high = float(top), float(top + np.linalg.norm(g)) + 1e-12   # |n(mu)| falls from inf to <= 1 here
        (g0, g1, g2), (e0, e1, e2) = g.tolist(), eigen.tolist()
        for _ in range(60):                                  # bisection in plain floats: 3 terms, no array overhead
            mu = 0.5 * (low + high)
            if mu <= e2 or (g0 / (mu - e0)) ** 2 + (g1 / (mu - e1)) ** 2 + (g2 / (mu - e2)) ** 2 > 1.0:
                low = mu
            else:
                high = mu
        coords = g / np.maximum(high - eigen, 1e-300)
        if np.linalg.norm(coords) < 1.0 - 1e-6:             # hard case: mu = top, the rest along its eigenvector
            coords = np.append(g[:2] / np.maximum(top - eigen[:2], 1e-12), 0.0)
            coords[2] = np.sqrt(max(1.0 - np.sum(coords[:2] ** 2), 0.0))
        axis = basis @ coords
        axis /= np.linalg.norm(axis)
    k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.cos(theta) * np.eye(3) + np.sin(theta) * k + (1.0 - np.cos(theta)) * np.outer(axis, axis)


def tilted_within(rotation: np.ndarray, vertical: np.ndarray, bound_deg: float) -> np.ndarray:
    """(..., 3, 3) ``rotation`` with its tilt (how far it turns ``vertical``) cut to ``bound_deg``: turned back about
    the axis between the turned and the true vertical, its heading kept. The gravity start's bound."""
    rotation = np.asarray(rotation, dtype=float)
    turned = np.einsum("...ij,j->...i", rotation, vertical)
    tilt = np.arccos(np.clip(turned @ vertical, -1.0, 1.0))
    excess = np.maximum(tilt - np.radians(bound_deg), 0.0)
    axis = np.cross(turned, vertical)
    axis /= np.maximum(np.linalg.norm(axis, axis=-1, keepdims=True), 1e-12)
    k = np.zeros(rotation.shape)
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -axis[..., 2], axis[..., 1], -axis[..., 0]
    k -= np.swapaxes(k, -1, -2)
    sin, cos = np.sin(excess)[..., None, None], np.cos(excess)[..., None, None]
    back = np.eye(3) + sin * k + (1.0 - cos) * k @ k
    return back @ rotation


def fit_within_bounds(problem: Problem, source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(4, 4) correction minimising the squared distances of ``source`` (K, 3, initial-aligned preop) moved onto
    ``target`` (K, 3) with rotation angle <= ``max_rotation_deg`` (from a gravity start: tilt <= its bound, the best
    rotation's tilt cut back) and centroid shift <= ``max_translation_mm``."""
    centre = problem.centre
    if problem.vertical is not None:
        q, y = source - centre, target - centre
        q_mean, y_mean = q.mean(axis=0), y.mean(axis=0)
        rotation = tilted_within(_best_rotation((y - y_mean).T @ (q - q_mean), np.pi), problem.vertical,
                                 problem.rotation_bound_deg)
        shift = y_mean - rotation @ q_mean
        shift *= min(1.0, problem.max_translation_mm / max(np.linalg.norm(shift), 1e-12))
        return geometry.make_transform(rotation, centre + shift - rotation @ centre)
    theta = np.radians(problem.max_rotation_deg)
    q = source - centre                      # about the preop centroid, whose displacement is bounded
    y = target - centre
    q_mean, y_mean = q.mean(axis=0), y.mean(axis=0)
    rotation = _best_rotation((y - y_mean).T @ (q - q_mean), theta)
    for _ in range(_ALTERNATIONS):
        shift = y_mean - rotation @ q_mean
        length = np.linalg.norm(shift)
        if length <= problem.max_translation_mm:
            break
        shift *= problem.max_translation_mm / length
        rotation = _best_rotation((y - shift).T @ q, theta)
    else:
        shift = y_mean - rotation @ q_mean
        shift *= min(1.0, problem.max_translation_mm / max(np.linalg.norm(shift), 1e-12))
    return geometry.make_transform(rotation, centre + shift - rotation @ centre)
