"""Where each preop node really is: a 90% bound on the distance between its mapped position and the truth.

Why: the surgeon's question for a SPECT node not removed yet is "where is it?", and the mapped position is only as
good as the registration and the node's own preop-to-intraop error. Following Fitzpatrick and West's target
registration error (TRE) for a point-based rigid fit with isotropic error sigma per axis, a point r from the
centroid of K paired nodes is displaced by the fitted correction's error with covariance

    sigma^2 (I / K + [r]x J^-1 [r]x^T)      (J: inertia tensor of the paired nodes about their centroid)

and the node itself lies where it is stored with its own error sigma^2 I (the same error every stored node has).
sigma is not known: its posterior under the fit's residual (3K - 6 degrees of freedom) and the log-uniform prior
of :mod:`snreg.registration._model` is integrated over, and so are the candidate pairings with their posterior
weights (a wrong pairing moves every mapped node). The bound is the 90th percentile of the distance from the
reported mapped position, drawn by Monte Carlo from that mixture under a fixed seed (deterministic). With
covariances per node the fit's uncertainty is the weighted fit's (its inverse Hessian carried to each node) and the
node's own error is its hot spot's covariance plus the unmodelled error (:mod:`snreg.registration._covariance`).
"""

from __future__ import annotations

import numpy as np

from snreg import geometry
from snreg.registration._covariance import correction_covariances
from snreg.registration._model import Candidate, candidate_sigmas, unmodelled_grid
from snreg.registration._problem import Problem

__all__ = ["target_error_bound", "rigid_fit_covariance", "COVERAGE", "SAMPLES"]

COVERAGE = 0.90
SAMPLES = 2000
_WEIGHT_KEPT = 0.995          # candidates beyond this much posterior weight are left out of the mixture
_MAX_COMPONENTS = 8


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) cross-product matrices of vectors (..., 3)."""
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    zero = np.zeros_like(x)
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)


def _shape_factors(problem: Problem, cand: Candidate) -> tuple[np.ndarray, np.ndarray]:
    """Mapped preop nodes (N, 3) under the candidate, and (N, 3, 3) Cholesky factors of the per-unit-sigma covariance
    of where each node really is about its mapped position."""
    mapped = geometry.apply(cand.correction, problem.preop)
    paired = mapped[cand.assignment[cand.assignment >= 0]]
    cov = np.eye(3) + rigid_fit_covariance(paired, mapped)
    return mapped, np.linalg.cholesky(cov)


def rigid_fit_covariance(fiducials: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(M, 3, 3) covariance, per unit error variance per axis of the K fiducials (K, 3), of where a least-squares rigid
    fit to them puts the targets (M, 3): ``I / K + [r]x J^-1 [r]x^T`` with r from the fiducials' centroid and J their
    inertia tensor (Fitzpatrick and West's target registration error; its trace is their TRE^2 / FLE_axis^2)."""
    centroid = fiducials.mean(axis=0)
    centred = fiducials - centroid
    inertia = np.sum(centred**2) * np.eye(3) - centred.T @ centred
    inertia_inv = np.linalg.pinv(inertia + 1e-6 * np.trace(inertia) * np.eye(3))
    skew = _skew(np.asarray(targets, dtype=float) - centroid)
    return np.eye(3) / len(fiducials) + skew @ inertia_inv @ np.swapaxes(skew, -1, -2)


def target_error_bound(problem: Problem, correction: np.ndarray, candidates: list[Candidate],
                       weights: np.ndarray) -> np.ndarray:
    """(N,) the 90% bound (mm) on the distance between each preop node mapped by ``correction`` (problem frame) and
    where it really is, over the candidate pairings (best first) with their posterior ``weights``."""
    rng = np.random.default_rng(problem.seed)
    keep = min(int(np.searchsorted(np.cumsum(weights), _WEIGHT_KEPT)) + 1, _MAX_COMPONENTS)
    cands, w = candidates[:keep], weights[:keep] / weights[:keep].sum()
    counts = rng.multinomial(SAMPLES, w)
    reported = geometry.apply(correction, problem.preop)
    distances = []
    for cand, count in zip(cands, counts):
        if count == 0:
            continue
        sigmas, sigma_weights = candidate_sigmas(problem, cand)
        if problem.weighted:
            truth = _weighted_draws(problem, cand, rng.choice(len(sigmas), size=count, p=sigma_weights), rng)
        else:
            mapped, factors = _shape_factors(problem, cand)
            sigma = rng.choice(sigmas, size=count, p=sigma_weights)
            z = rng.standard_normal((count, 3))
            truth = mapped[:, None, :] + sigma[None, :, None] * np.einsum("nij,sj->nsi", factors, z)
        distances.append(np.linalg.norm(truth - reported[:, None, :], axis=-1))
    return np.quantile(np.concatenate(distances, axis=1), COVERAGE, axis=1)


def _weighted_draws(problem: Problem, cand: Candidate, s_index: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(N, S) draws of where each preop node really is under the candidate with covariances or landmarks, the
    unmodelled error at the grid indices ``s_index`` (S,): the fit's uncertainty at each node plus its own (the hot
    spot's covariance turned, and the unmodelled error)."""
    mapped = geometry.apply(cand.correction, problem.preop)
    rotation = cand.correction[:3, :3]
    own = (rotation @ problem.preop_cov @ rotation.T) if problem.preop_cov is not None else np.zeros((len(mapped), 3, 3))
    drawn = np.unique(s_index)
    s = unmodelled_grid(problem)[drawn]
    cov = (correction_covariances(problem, cand.assignment, cand.correction, s, mapped) + own[None]
           + (s**2)[:, None, None, None] * np.eye(3))                                      # (S, N, 3, 3)
    factors = np.linalg.cholesky(cov)
    truth = np.empty((len(mapped), len(s_index), 3))
    for k, index in enumerate(drawn):
        chosen = np.flatnonzero(s_index == index)
        z = rng.standard_normal((len(chosen), 3))
        truth[:, chosen] = mapped[:, None, :] + np.einsum("nij,sj->nsi", factors[k], z)
    return truth
