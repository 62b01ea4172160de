"""The probabilistic model every candidate pairing is judged by: pairs, extra intraop nodes and missing preop nodes.

Generative model (mm): a rigid correction D maps each preop node (SPECT hot spot) p_n near where its node lies in the
intraop frame. Each hot spot's own node is found during surgery with probability ``PI_FOUND`` (thesis Table 1: 57 of
65 imaged nodes were removed); a found node is stored at D p_n plus isotropic Gaussian error of unknown size sigma
(per axis). Every other removed node is an extra, which lies beside a hot spot's node or anywhere
(:mod:`snreg.registration._extras`: the density rho_sigma, which depends on the pairing through the own nodes the
extras lie beside). A candidate pairing ``a`` (intraop m -> its hot spot's own node, or -1 for an extra) with
K >= 3 own nodes is scored by its negative log posterior in nats, the correction fitted (Kabsch, within the bounds)
and its uncertainty integrated by Laplace's method, sigma integrated numerically under a log-uniform prior:

    score(a) = -log E_sigma[(2 pi sigma^2)^(-(3K - 6)/2) exp(-SSE_a / (2 sigma^2)) prod_extras rho_sigma(x_m | a)]
               + 1.5 log K + 0.5 log det J_a                                  (Occam factor of the correction)
               + K C_FOUND + (N - K) C_MISSING - E log EXTRAS_EXPECTED        (found, missing, E extras)
               + prior(D_a) + label nats of the pairs

with J_a the inertia tensor of the paired preop nodes. The number of own nodes is decided by this evidence, not by
min(N, M). Under a fixed sigma the best pairing for a correction is nearly a linear assignment in which every preop
node may go unpaired (cost C_MISSING) and every intraop node may be extra (its cost beside the mapped hot spots, the
own nodes not known yet); the score then judges it with the extras beside the own nodes.

With covariances per node (``intraop_cov``/``preop_cov``) the isotropic error becomes each pair's own Gaussian plus an
unmodelled isotropic part, fitted and integrated the same way (:mod:`snreg.registration._covariance`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from snreg import geometry
from snreg.registration._bounded import fit_within_bounds
from snreg.registration._covariance import S_GRID_MM, blur_sigmas, fit_corrections, fit_nats, pair_nats_given
from snreg.registration._extras import (ANYWHERE_LOG, EXTRA_NEAR_FRACTION, anchored, anchored_extra_nats,
                                        anchored_near_log, extra_nats, logsumexp)
from snreg.registration._problem import Problem

__all__ = ["Candidate", "squared_distances", "pair_nats", "pair_costs", "assign", "evaluate", "fit_pairs", "score_many",
           "refine_many", "sigma_weights", "candidate_sigmas", "unmodelled_grid", "source_posterior", "SIGMA_GRID_MM",
           "MIN_PAIRS"]

MIN_PAIRS = 3
PI_FOUND = 0.9                    # a SPECT node is found (and stored) during surgery
SIGMA_GRID_MM = np.geomspace(2.0, 40.0, 32)   # support of the log-uniform prior on the intraop error sigma
ASSIGN_SIGMAS_MM = (3.0, 6.0, 12.0)          # sigmas at which candidate pairings are assigned
C_FOUND = -np.log(PI_FOUND)
C_MISSING = -np.log(1.0 - PI_FOUND)
_LOG_2PI = np.log(2.0 * np.pi)
_FORBIDDEN = 1e9
_J_FLOOR_MM2 = 25.0               # inertia eigenvalues below this (nearly collinear pairs) are floored


@dataclass(frozen=True)
class Candidate:
    """A partial one-to-one pairing: ``assignment[m]`` is the hot spot whose own node intraop m is, or -1 (an extra);
    the correction fitted to its pairs, their sum of squared residuals (mm^2) and the score (nats, lower is better).
    The unmodelled error's posterior is :func:`candidate_sigmas`'."""

    assignment: np.ndarray
    correction: np.ndarray
    sse: float
    score: float
    fit_weights: np.ndarray | None = None      # with covariances or landmarks: the unmodelled error's posterior

    @property
    def key(self) -> bytes:
        return self.assignment.astype(np.int16).tobytes()

    @property
    def n_pairs(self) -> int:
        return int(np.sum(self.assignment >= 0))


def squared_distances(moved_preop: np.ndarray, intraop: np.ndarray) -> np.ndarray:
    """(..., N, M) squared distances between (moved) preop nodes (..., N, 3) and intraop nodes (M, 3)."""
    diff = moved_preop[..., :, None, :] - intraop
    return np.einsum("...k,...k->...", diff, diff)


def pair_nats(d2: np.ndarray, sigma: float, label_nats: np.ndarray) -> np.ndarray:
    """Cost of each pair at a fixed sigma: Gaussian error of the stored node, found, labels."""
    return d2 / (2.0 * sigma**2) + 1.5 * (_LOG_2PI + 2.0 * np.log(sigma)) + C_FOUND + label_nats


def source_posterior(problem: Problem, cand: "Candidate", sigma: float | None = None) -> np.ndarray:
    """(M, N + 1) probability that intraop node m came from hot spot n under the candidate; column N: from no hot spot.

    An own node comes from its preop node. An extra came from hot spot n in proportion to the density of an extra
    beside n's node (labels included; :mod:`~snreg.registration._extras`), or from none in proportion to the density
    anywhere; sigma is integrated over its posterior given the candidate's fit, unless given."""
    n, m = len(problem.preop), len(problem.intraop)
    d2 = squared_distances(geometry.apply(cand.correction, problem.preop), problem.intraop)        # (N, M)
    sigmas, weights = candidate_sigmas(problem, cand) if sigma is None else (np.array([float(sigma)]), np.ones(1))
    near = (anchored_near_log(*anchored(problem.intraop, cand.assignment[None], d2[None]), sigmas)[0]
            + np.log(EXTRA_NEAR_FRACTION / n) - problem.label_nats[None])                          # (G, N, M)
    anywhere = np.full((len(sigmas), 1, m), ANYWHERE_LOG)
    logs = np.concatenate([near, anywhere], axis=1)                                                  # (G, N+1, M)
    resp = np.exp(logs - logsumexp(logs, axis=1)[:, None, :])
    extra = np.einsum("g,gnm->mn", weights, resp)                                                     # (M, N+1)
    own = np.zeros((m, n + 1))
    paired = cand.assignment >= 0
    own[np.flatnonzero(paired), cand.assignment[paired]] = 1.0
    return np.where(paired[:, None], own, extra)


def unmodelled_grid(problem: Problem) -> np.ndarray:
    """The support of the unmodelled isotropic error's prior: down to a quarter mm when nodes carry covariances (they
    may be the whole error), the isotropic model's sigma grid when they do not."""
    return S_GRID_MM if problem.anisotropic else SIGMA_GRID_MM


def candidate_sigmas(problem: Problem, cand: Candidate) -> tuple[np.ndarray, np.ndarray]:
    """The candidate's posterior over the intraop error's scale: (G,) isotropic sds (mm) and their weights. In the
    isotropic model, sigma given the fit; with covariances or landmarks, the blur standing for each unmodelled ``s``."""
    if cand.fit_weights is None:
        return SIGMA_GRID_MM, sigma_weights(cand.sse, cand.n_pairs)
    return blur_sigmas(problem, unmodelled_grid(problem)), cand.fit_weights


def pair_costs(problem: Problem, corrections: np.ndarray, sigmas) -> tuple[np.ndarray, np.ndarray]:
    """(A, N, M) pair costs and (A, M) extra costs under corrections (A, 4, 4) at the assignment sigmas (A,): the
    nodes' own covariances plus sigma when given, else sigma alone."""
    sigmas = np.broadcast_to(np.asarray(sigmas, dtype=float), (len(corrections),))
    d2 = squared_distances(_moved(problem, corrections), problem.intraop)
    if not problem.anisotropic:          # isotropic nodes (with or without landmarks)
        return pair_nats(d2, sigmas[:, None, None], problem.label_nats), extra_nats(d2, sigmas)
    pairs = pair_nats_given(problem, corrections, sigmas) + C_FOUND + problem.label_nats
    return pairs, extra_nats(d2, blur_sigmas(problem, sigmas))


def _partial_lsa(pair: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """The assignment (M,) minimising pair costs (N, M) + C_MISSING per unpaired preop node + ``extra`` (M,) per
    unpaired intraop node, one linear assignment on the padded (N + M) x (M + N) matrix."""
    n, m = pair.shape
    cost = np.full((n + m, m + n), _FORBIDDEN)
    cost[:n, :m] = pair
    cost[np.arange(n), m + np.arange(n)] = C_MISSING
    cost[n + np.arange(m), np.arange(m)] = extra
    cost[n:, m:] = 0.0
    rows, cols = linear_sum_assignment(cost)
    assignment = np.full(m, -1, dtype=int)
    paired = (rows < n) & (cols < m)
    assignment[cols[paired]] = rows[paired]
    return assignment


def _moved(problem: Problem, corrections: np.ndarray) -> np.ndarray:
    """Preop nodes under each correction: (A, N, 3) for corrections (A, 4, 4)."""
    return problem.preop @ np.swapaxes(corrections[:, :3, :3], 1, 2) + corrections[:, None, :3, 3]


def assign(problem: Problem, correction: np.ndarray, sigma: float, adjust: np.ndarray | None = None) -> np.ndarray:
    """The best partial one-to-one pairing under ``correction`` at a fixed ``sigma``: a linear assignment over pairs,
    missing preop nodes and extra intraop nodes. ``adjust`` (N, M) is added to the pair costs (pins, bans).
    Returns the assignment (M,): preop index or -1."""
    pair, extra = pair_costs(problem, np.asarray(correction, float)[None], sigma)
    return _partial_lsa(pair[0] + (0.0 if adjust is None else adjust), extra[0])


def _fit(problem: Problem, assignments: np.ndarray, bounded: bool = True,
         sigmas=None) -> tuple[np.ndarray, np.ndarray]:
    """Corrections (A, 4, 4) of pairings (A, M) (each with >= 3 pairs) and their residuals (A,) mm^2: Kabsch, or with
    covariances the weighted fit at the unmodelled error ``sigmas`` (A,) (None: the Kabsch residual's sigma); when
    ``bounded``, a correction that leaves the bounds is replaced by the pairing's best fit within them."""
    paired = assignments >= 0
    src = problem.preop[np.maximum(assignments, 0)]                     # (A, M, 3)
    if problem.n_landmarks:          # Kabsch over the nodes and the landmark pairs, the weighted fit from there
        marks = problem.landmarks
        count = len(assignments)
        corrections = geometry.kabsch(
            np.concatenate([src, np.broadcast_to(marks.preop, (count,) + marks.preop.shape)], axis=1),
            np.broadcast_to(np.vstack([problem.intraop, marks.intraop]), (count, paired.shape[1] + len(marks), 3)),
            np.concatenate([paired, np.ones((count, len(marks)), bool)], axis=1).astype(float))
    else:
        corrections = geometry.kabsch(src, np.broadcast_to(problem.intraop, src.shape), paired.astype(float))
    if problem.weighted:
        if sigmas is None:
            sigmas = _residual_sigma(problem, src, corrections, paired)
        corrections = fit_corrections(problem, assignments, corrections, sigmas)
    if bounded:
        marks = problem.landmarks if problem.n_landmarks else None
        for a in np.flatnonzero(~problem.within_bounds(corrections)):
            source, target = src[a][paired[a]], problem.intraop[paired[a]]
            if marks is not None:
                source, target = np.vstack([source, marks.preop]), np.vstack([target, marks.intraop])
            corrections[a] = fit_within_bounds(problem, source, target)
    residual = src @ np.swapaxes(corrections[:, :3, :3], 1, 2) + corrections[:, None, :3, 3] - problem.intraop
    return corrections, np.einsum("amk,amk,am->a", residual, residual, paired)


def _residual_sigma(problem: Problem, src: np.ndarray, corrections: np.ndarray, paired: np.ndarray) -> np.ndarray:
    """(A,) the sigma of corrections' isotropic residuals less what the given covariances explain (at least the
    smallest of the unmodelled grid): where the weighted fit starts."""
    residual = src @ np.swapaxes(corrections[:, :3, :3], 1, 2) + corrections[:, None, :3, 3] - problem.intraop
    k = paired.sum(axis=1)
    per_axis = np.einsum("amk,amk,am->a", residual, residual, paired) / np.maximum(3 * k - 6, 1)
    explained = blur_sigmas(problem, 0.0) ** 2
    return np.sqrt(np.maximum(per_axis - explained, unmodelled_grid(problem)[0] ** 2))


def fit_pairs(problem: Problem, assignment: np.ndarray, sigma: float | None = None) -> np.ndarray:
    """(4, 4) the correction fitted to one pairing (M,) (at least 3 pairs), without bounds: Kabsch, or with covariances
    the weighted fit at the unmodelled error ``sigma`` (None: from the residual)."""
    sigmas = None if sigma is None else np.array([float(sigma)])
    return _fit(problem, np.asarray(assignment, dtype=int)[None], bounded=False, sigmas=sigmas)[0][0]


def score_many(problem: Problem, assignments: np.ndarray, bounded: bool = True) -> list[Candidate]:
    """Fit and score pairings (A, M), each with at least :data:`MIN_PAIRS` pairs (module docstring); ``bounded``: fits
    kept within the bounds."""
    assignments = np.asarray(assignments, dtype=int).reshape(-1, len(problem.intraop))
    corrections, sse = _fit(problem, assignments, bounded)
    paired = assignments >= 0
    k = paired.sum(axis=1)
    if problem.weighted:            # refitted at the unmodelled error the first fit makes most likely
        unmodelled = unmodelled_grid(problem)
        best_s = unmodelled[np.argmin(fit_nats(problem, assignments, corrections, unmodelled), axis=1)]
        corrections, sse = _fit(problem, assignments, bounded, best_s)
        fit_terms = fit_nats(problem, assignments, corrections, unmodelled)     # the Occam factor included
        occam = 0.0
        grid = blur_sigmas(problem, unmodelled)
    else:
        fit_terms = _fit_terms(sse, k)
        occam = _occam_nats(problem, assignments)
        grid = SIGMA_GRID_MM
    d2 = squared_distances(_moved(problem, corrections), problem.intraop)          # (A, N, M)
    extra = anchored_extra_nats(*anchored(problem.intraop, assignments, d2), grid)  # (A, G, M)
    per_sigma = fit_terms + np.where(paired[:, None, :], 0.0, extra).sum(axis=2)
    fit = -(logsumexp(-per_sigma, axis=1) - np.log(len(grid)))
    outliers = found_nats(k, len(problem.preop))
    rows, cols = np.nonzero(paired)
    labels = np.zeros(len(assignments))
    np.add.at(labels, rows, problem.label_nats[assignments[rows, cols], cols])
    scores = fit + occam + outliers + problem.prior_nats(corrections) + labels
    weights = [None] * len(assignments)
    if problem.weighted:
        posterior = np.exp(-(fit_terms - fit_terms.min(axis=1, keepdims=True)))
        weights = list(posterior / posterior.sum(axis=1, keepdims=True))
    return [Candidate(a.copy(), c, float(e), float(s), w)
            for a, c, e, s, w in zip(assignments, corrections, sse, scores, weights)]


def found_nats(k: np.ndarray, n: int) -> np.ndarray:
    """Nats of K of the N preop nodes being found (the rest missing)."""
    return k * C_FOUND + (n - k) * C_MISSING


def evaluate(problem: Problem, assignment: np.ndarray) -> Candidate | None:
    """Fit (Kabsch) and score one pairing; None when it has fewer pairs than the problem needs (:data:`MIN_PAIRS`
    less its landmark pairs)."""
    if np.sum(assignment >= 0) < problem.min_pairs:
        return None
    return score_many(problem, assignment[None])[0]


def refine_many(problem: Problem, corrections: np.ndarray, sigmas, adjusts: np.ndarray | None = None,
                iterations: int = 8, bounded: bool = True) -> list[Candidate]:
    """Alternate :func:`assign` and Kabsch from each start correction (A, 4, 4) at its sigma (A,) until its pairing
    repeats; ``adjusts`` (A, N, M) are added to the pair costs (pins, bans). The scored pairings (those that keep at
    least :data:`MIN_PAIRS` pairs), in no particular order."""
    corrections = np.array(corrections, dtype=float).reshape(-1, 4, 4)
    count = len(corrections)
    sigmas = np.broadcast_to(np.asarray(sigmas, dtype=float), (count,))
    assignments = np.full((count, len(problem.intraop)), -2)      # -2: not assigned yet
    valid, active = np.ones(count, bool), np.ones(count, bool)
    for _ in range(iterations):
        index = np.flatnonzero(active)
        if len(index) == 0:
            break
        pair, extra = pair_costs(problem, corrections[index], sigmas[index])
        if adjusts is not None:
            pair = pair + adjusts[index]
        updated = np.array([_partial_lsa(p, e) for p, e in zip(pair, extra)])
        too_few = (updated >= 0).sum(axis=1) < problem.min_pairs    # keep the last pairing that had enough
        valid[index[too_few & (assignments[index] == -2).all(axis=1)]] = False
        settled = too_few | np.all(updated == assignments[index], axis=1)
        assignments[index[~too_few]] = updated[~too_few]
        active[index[settled]] = False
        moving = index[~settled]
        corrections[moving], _ = _fit(problem, assignments[moving], bounded, sigmas[moving])
    return score_many(problem, assignments[valid], bounded) if valid.any() else []


def sigma_weights(sse: float, n_pairs: int) -> np.ndarray:
    """Posterior weights of :data:`SIGMA_GRID_MM` (log-uniform prior) given a fit's residual and its pair count."""
    log_like = -_fit_terms(np.asarray([sse], float), np.asarray([n_pairs]))[0]
    return np.exp(log_like - logsumexp(log_like, axis=0))


def _fit_terms(sse: np.ndarray, n_pairs: np.ndarray) -> np.ndarray:
    """(A, G) nats of the fit at every grid sigma, for fits (A,) with ``n_pairs`` pairs each."""
    dof = 3.0 * n_pairs[:, None] - 6.0
    sigma2 = SIGMA_GRID_MM[None, :] ** 2
    return sse[:, None] / (2.0 * sigma2) + 0.5 * dof * (_LOG_2PI + np.log(sigma2))


def _occam_nats(problem: Problem, assignments: np.ndarray) -> np.ndarray:
    """(A,) 1.5 log K + 0.5 log det J of each pairing's paired preop nodes: how tightly its pairs pin the correction."""
    paired = (assignments >= 0).astype(float)                      # (A, M)
    points = problem.preop[np.maximum(assignments, 0)]             # (A, M, 3)
    k = paired.sum(axis=1)
    centre = np.einsum("am,amk->ak", paired, points) / k[:, None]
    centred = (points - centre[:, None]) * paired[..., None]
    outer = np.einsum("amk,aml->akl", centred, centred)
    inertia = np.trace(outer, axis1=1, axis2=2)[:, None, None] * np.eye(3) - outer
    eigen = np.maximum(np.linalg.eigvalsh(inertia), _J_FLOOR_MM2)
    return 1.5 * np.log(k) + 0.5 * np.log(eigen).sum(axis=1)
