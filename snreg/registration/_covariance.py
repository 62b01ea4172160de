"""Each node with its own error: the model of :mod:`snreg.registration._model` when covariances or landmarks are given.

Why: a stereo fix is uncertain mostly along its viewing ray (at 80 mm with the Firefly's 4.3 mm baseline, about 19
times more than across it), and each node is seen along another ray; weighing every node as an isotropic point throws
that shape away (Maier-Hein et al. 2012, anisotropic and inhomogeneous localisation error; Danilchenko and Fitzpatrick
2011, first-order error prediction in rigid point registration).

Model: a pair's residual ``r = D p_n - x_m`` is Gaussian with covariance ``C = S_m + R S_n R^T + s^2 I``: the intraop
node's given covariance, the hot spot's given covariance turned by the correction's rotation, and what neither
accounts for (deformation, a model that is off), isotropic with ``s`` unknown under a log-uniform prior on
``S_GRID_MM`` (it reaches near zero: given covariances may be the whole error). The correction is fitted by weighted
Gauss-Newton from Kabsch, and integrated by Laplace's method as the isotropic model does: per ``s``

    nats(s) = 1/2 sum r^T C^-1 r + 1/2 sum log det(2 pi C) - 3 log(2 pi) + 1/2 log det H,   H = sum J^T C^-1 J

with ``J = [-[D p - c]x, I]`` the residual's derivative by a small turn about the paired centroid ``c`` and a shift.
With ``S = 0`` this is the isotropic model's fit term and Occam factor exactly. Landmark pairs
(:mod:`snreg.registration._landmarks`) are pairs of known correspondence whose covariance is their own error alone
(no ``s``). Each ``C`` is diagonalised once per correction, so every ``s`` of the grid costs a division. Extras keep the isotropic density of
:mod:`snreg.registration._extras`, blurred by ``s`` and the nodes' mean given variance.
"""

from __future__ import annotations

import warnings

import numpy as np

from snreg import geometry

__all__ = ["S_GRID_MM", "covariances", "given_covariance", "fit_corrections", "fit_nats", "pair_nats_given",
           "blur_sigmas", "correction_covariances", "IllConditionedWarning", "CONDITION_LIMIT"]

S_GRID_MM = np.geomspace(0.25, 40.0, 40)    # support of the log-uniform prior on the unmodelled isotropic error
MAX_SD_MM = 1e3                             # a node's sd beyond a metre is a unit error
_LOG_2PI = np.log(2.0 * np.pi)
_GAUSS_NEWTON_STEPS = 4
CONDITION_LIMIT = 1e12                      # a fit's Hessian beyond this is not inverted silently


class IllConditionedWarning(UserWarning):
    """A fit whose pairs do not determine the correction in every direction (nearly collinear points)."""


def covariances(name: str, value, count: int) -> np.ndarray | None:
    """(count, 3, 3) covariances (mm^2) from ``value``: None, one sd in mm for every node, or (count, 3, 3) symmetric
    positive semi-definite matrices; ValueError in one sentence otherwise."""
    if value is None:
        return None
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}_cov must be ({count}, 3, 3) covariances in mm^2 or one sd in mm") from None
    if array.ndim == 0:
        sd = float(array)
        if not (np.isfinite(sd) and 0.0 <= sd <= MAX_SD_MM):
            raise ValueError(f"{name}_cov as one sd must be a number of mm from 0 to {MAX_SD_MM:g}, got {sd}")
        return np.broadcast_to(sd**2 * np.eye(3), (count, 3, 3)).copy()
    if array.shape != (count, 3, 3):
        raise ValueError(f"{name}_cov must be ({count}, 3, 3) covariances in mm^2, one per {name} node, or one sd in "
                         f"mm; got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name}_cov contains NaN or infinite values; give every {name} node a finite covariance")
    scale = max(float(np.abs(array).max()), 1e-12)
    if np.abs(array - np.swapaxes(array, 1, 2)).max() > 1e-6 * scale:
        raise ValueError(f"{name}_cov must hold symmetric 3x3 matrices (a covariance in mm^2 per node)")
    symmetric = 0.5 * (array + np.swapaxes(array, 1, 2))
    eigen = np.linalg.eigvalsh(symmetric)
    if eigen.min() < -1e-9 * scale:
        k = int(np.argmin(eigen.min(axis=1)))
        raise ValueError(f"{name}_cov of node {k} is not a covariance: it has a negative variance "
                         f"({eigen[k].min():.3g} mm^2)")
    if eigen.max() > MAX_SD_MM**2:
        raise ValueError(f"{name}_cov reaches a variance of {eigen.max():.3g} mm^2 (sd over {MAX_SD_MM:g} mm): "
                         "covariances must be in mm^2")
    return symmetric


def given_covariance(problem, rotations: np.ndarray, assignments: np.ndarray | None = None) -> np.ndarray:
    """The given covariances of pairs: (A, N, M, 3, 3) for every preop-intraop pair under corrections with rotations
    (A, 3, 3), or (A, M, 3, 3) for intraop m paired with ``assignments[a, m]`` (unpaired nodes get the intraop part)."""
    n, m = len(problem.preop), len(problem.intraop)
    count = len(rotations)
    intra = problem.intraop_cov if problem.intraop_cov is not None else np.zeros((m, 3, 3))
    pre = problem.preop_cov
    if assignments is None:
        total = np.broadcast_to(intra[None, None], (count, n, m, 3, 3)).copy()
        if pre is not None:
            turned = rotations[:, None] @ pre[None] @ np.swapaxes(rotations, 1, 2)[:, None]       # (A, N, 3, 3)
            total += turned[:, :, None]
        return total
    total = np.broadcast_to(intra[None], (count, m, 3, 3)).copy()
    if pre is not None:
        spots = pre[np.maximum(assignments, 0)]                                                  # (A, M, 3, 3)
        turned = rotations[:, None] @ spots @ np.swapaxes(rotations, 1, 2)[:, None]
        total += np.where((assignments >= 0)[..., None, None], turned, 0.0)
    return total


def _jacobians(moved: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(A, M, 3, 6) derivatives of moved points (A, M, 3) by a small turn about ``centre`` (A, 3) and a shift."""
    v = moved - centre[:, None]
    jac = np.zeros(moved.shape[:2] + (3, 6))
    jac[..., 0, 1], jac[..., 0, 2] = v[..., 2], -v[..., 1]
    jac[..., 1, 0], jac[..., 1, 2] = -v[..., 2], v[..., 0]
    jac[..., 2, 0], jac[..., 2, 1] = v[..., 1], -v[..., 0]
    jac[..., :, 3:] = np.eye(3)
    return jac


def _eigen(problem, rotations: np.ndarray, assignments: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues and eigenvectors of :func:`given_covariance`: the intraop nodes' own, decomposed once, when the hot
    spots carry no covariance (the pairs' then do not depend on the correction)."""
    if problem.preop_cov is None:
        eigen, vectors = problem.intraop_eigen
        shape = (len(rotations),) + ((len(problem.preop),) if assignments is None else ())
        return (np.broadcast_to(eigen, shape + (len(problem.intraop), 3)),
                np.broadcast_to(vectors, shape + (len(problem.intraop), 3, 3)))
    eigen, vectors = np.linalg.eigh(given_covariance(problem, rotations, assignments))
    return np.maximum(eigen, 0.0), vectors


def _paired_terms(problem, assignments: np.ndarray, corrections: np.ndarray):
    """The pairs' rows: the M intraop nodes, then the L landmark pairs (always paired, their error fixed): residuals
    (A, R, 3), Jacobians (A, R, 3, 6), the given covariances' eigenvalues (A, R, 3) and eigenvectors (A, R, 3, 3), the
    pair mask (A, R), which rows take the unmodelled error (R,), and the pairs' centroid (A, 3)."""
    paired = assignments >= 0
    src = problem.preop[np.maximum(assignments, 0)]
    target = problem.intraop
    eigen, vectors = _eigen(problem, corrections[:, :3, :3], assignments)
    count, m, landmarks = len(corrections), len(problem.intraop), problem.n_landmarks
    if landmarks:
        marks = problem.landmarks
        src = np.concatenate([src, np.broadcast_to(marks.preop, (count, landmarks, 3))], axis=1)
        target = np.vstack([target, marks.intraop])
        paired = np.concatenate([paired, np.ones((count, landmarks), bool)], axis=1)
        eigen = np.concatenate([eigen, np.full((count, landmarks, 3), marks.sd_mm**2)], axis=1)
        vectors = np.concatenate([vectors, np.broadcast_to(np.eye(3), (count, landmarks, 3, 3))], axis=1)
    unmodelled = np.arange(m + landmarks) < m
    moved = src @ np.swapaxes(corrections[:, :3, :3], 1, 2) + corrections[:, None, :3, 3]
    weights = paired.astype(float)
    centre = np.einsum("am,amk->ak", weights, moved) / np.maximum(weights.sum(axis=1), 1.0)[:, None]
    return moved - target, _jacobians(moved, centre), eigen, vectors, paired, unmodelled, centre


def fit_corrections(problem, assignments: np.ndarray, corrections: np.ndarray, s_mm) -> np.ndarray:
    """Corrections (A, 4, 4) minimising the pairs' Mahalanobis residuals (landmark pairs' included) at the unmodelled
    error ``s_mm`` (scalar or (A,)), by Gauss-Newton from ``corrections`` (Kabsch's, say)."""
    corrections = np.array(corrections, dtype=float)
    s2 = np.broadcast_to(np.asarray(s_mm, dtype=float) ** 2, (len(corrections),))
    for _ in range(_GAUSS_NEWTON_STEPS):
        residual, jac, eigen, vectors, paired, unmodelled, centre = _paired_terms(problem, assignments, corrections)
        inverse = paired[..., None] / (eigen + s2[:, None, None] * unmodelled[None, :, None])   # (A, R, 3)
        rotated_r = np.einsum("amki,amk->ami", vectors, residual)                           # V^T r
        rotated_j = np.einsum("amki,amkp->amip", vectors, jac)                              # V^T J
        hessian = np.einsum("amip,ami,amiq->apq", rotated_j, inverse, rotated_j)
        gradient = np.einsum("amip,ami,ami->ap", rotated_j, inverse, rotated_r)
        step = -np.linalg.solve(hessian + 1e-9 * np.eye(6), gradient[..., None])[..., 0]
        turn = _rotations(step[:, :3])
        about = geometry.make_transform(turn, centre + step[:, 3:] - np.einsum("aij,aj->ai", turn, centre))
        corrections = about @ corrections
    return corrections


def fit_nats(problem, assignments: np.ndarray, corrections: np.ndarray, grid_mm: np.ndarray) -> np.ndarray:
    """(A, G) nats of each pairing's fit at its correction for every unmodelled error of ``grid_mm`` (G,) (module
    docstring): the Gaussian fit term of the node and landmark pairs and the correction's Occam factor together."""
    residual, jac, eigen, vectors, paired, unmodelled, _ = _paired_terms(problem, assignments, corrections)
    s2 = np.asarray(grid_mm, dtype=float) ** 2
    variance = eigen[:, None] + s2[None, :, None, None] * unmodelled[None, None, :, None]   # (A, G, R, 3)
    mask = paired[:, None, :, None]
    rotated_r = np.einsum("amki,amk->ami", vectors, residual)
    rotated_j = np.einsum("amki,amkp->amip", vectors, jac)
    quadratic = np.sum(mask * rotated_r[:, None] ** 2 / variance, axis=(2, 3))
    log_det = np.sum(mask * (_LOG_2PI + np.log(variance)), axis=(2, 3))
    hessian = np.einsum("amip,agmi,amiq->agpq", rotated_j, mask / variance, rotated_j)
    _, occam = np.linalg.slogdet(hessian + 1e-12 * np.eye(6))
    return 0.5 * quadratic + 0.5 * log_det - 3.0 * _LOG_2PI + 0.5 * occam


def pair_nats_given(problem, corrections: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """(A, N, M) Gaussian cost of pairing each preop with each intraop node under corrections (A, 4, 4), the
    unmodelled error at ``sigmas`` (A,): the Mahalanobis distance and the covariance's normalisation."""
    moved = problem.preop @ np.swapaxes(corrections[:, :3, :3], 1, 2) + corrections[:, None, :3, 3]
    residual = moved[:, :, None, :] - problem.intraop[None, None]                          # (A, N, M, 3)
    eigen, vectors = _eigen(problem, corrections[:, :3, :3])
    variance = eigen + (np.asarray(sigmas, float) ** 2)[:, None, None, None]
    rotated = np.einsum("anmki,anmk->anmi", vectors, residual)
    return 0.5 * np.sum(rotated**2 / variance + _LOG_2PI + np.log(variance), axis=-1)


def blur_sigmas(problem, sigmas) -> np.ndarray:
    """The isotropic sd standing for ``sigmas`` (any shape) plus the nodes' mean given variance per axis: how far an
    extra's anchor at a mapped hot spot is blurred (:mod:`snreg.registration._extras`)."""
    mean = 0.0
    for cov in (problem.intraop_cov, problem.preop_cov):
        if cov is not None:
            mean += float(np.trace(cov, axis1=1, axis2=2).mean()) / 3.0
    return np.sqrt(np.asarray(sigmas, dtype=float) ** 2 + mean)


def correction_covariances(problem, assignment: np.ndarray, correction: np.ndarray, s_mm: np.ndarray,
                           targets: np.ndarray) -> np.ndarray:
    """(S, T, 3, 3) covariance of where the correction puts ``targets`` (T, 3, problem frame, already moved) at each
    unmodelled error of ``s_mm`` (S,): the weighted fit's inverse H carried to each target (the anisotropic
    counterpart of Fitzpatrick and West's target error)."""
    _, jac, eigen, vectors, paired, unmodelled, centre = _paired_terms(problem, assignment[None], correction[None])
    s2 = (np.asarray(s_mm, float) ** 2)[:, None, None] * unmodelled[None, :, None]
    inverse = paired[0][None, :, None] / (eigen[0][None] + s2)
    rotated_j = np.einsum("mki,mkp->mip", vectors[0], jac[0])
    hessian = np.einsum("mip,smi,miq->spq", rotated_j, inverse, rotated_j)
    _check_conditioning(hessian)
    covariance = np.linalg.pinv(hessian)
    target_jac = _jacobians(np.asarray(targets, float)[None], centre)[0]                    # (T, 3, 6)
    return np.einsum("tip,spq,tjq->stij", target_jac, covariance, target_jac)


def _check_conditioning(hessian: np.ndarray) -> None:
    """Warn (:class:`IllConditionedWarning`, one sentence) when a fit's Hessian (S, 6, 6) is too ill-conditioned to
    invert: its pairs (nodes and landmarks) lie nearly on a line, so a turn about that line is not determined and the
    pseudo-inverse would report it as exactly known. The turn block is in mm^2 per radian^2 and the shift block in
    1, so a well-posed fit's condition number stays below the squared spread (about 1e5 mm^2); ``CONDITION_LIMIT``
    lies far beyond it."""
    condition = float(np.max(np.linalg.cond(hessian)))
    if not np.isfinite(condition) or condition > CONDITION_LIMIT:
        warnings.warn(IllConditionedWarning(
            f"the paired nodes and landmarks lie nearly on one line (condition number {condition:.1e}): the turn "
            "about that line is not determined and the target-error bounds understate it; store a node or touch a "
            "landmark away from that line"), stacklevel=3)


def _rotations(rotvecs: np.ndarray) -> np.ndarray:
    """(A, 3, 3) rotation matrices of rotation vectors (A, 3) (Rodrigues)."""
    angle = np.linalg.norm(rotvecs, axis=1)
    axis = rotvecs / np.maximum(angle, 1e-12)[:, None]
    k = np.zeros((len(rotvecs), 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    k -= np.swapaxes(k, 1, 2)
    sin, cos = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + sin * k + (1.0 - cos) * k @ k
