"""The probabilistic model every candidate pairing is judged by: pairs, extra intraop nodes and missing preop nodes.

Generative model (mm): a rigid correction D maps each preop node p_n near where its node lies in the intraop frame.
Each preop node is found during surgery with probability ``PI_FOUND``; a found node is stored at D p_n plus
isotropic Gaussian error of unknown size sigma (per axis). Extra intraop nodes (removed nodes that are not on the
SPECT), ``EXTRAS_EXPECTED`` of them on average, lie either anywhere in a pelvic volume ``EXTRA_VOLUME_MM3`` or,
with probability ``EXTRA_NEAR_FRACTION``, near one of the nodes: a lymph node of the same station, offset
``EXTRA_SPREAD_MM`` per axis from where that node truly is, so about its mapped position with spread
sqrt(EXTRA_SPREAD_MM^2 + sigma^2). A candidate pairing ``a`` (intraop m -> preop index or -1) with K >= 3 pairs is
scored by its negative log posterior in nats, the correction fitted (Kabsch) and its uncertainty integrated by
Laplace's method, sigma integrated numerically under a log-uniform prior:

    score(a) = -log E_sigma[(2 pi sigma^2)^(-(3K - 6)/2) exp(-SSE_a / (2 sigma^2)) prod_extras rho_sigma(x_m)]
               + 1.5 log K + 0.5 log det J_a                                  (Occam factor of the correction)
               + K C_FOUND + (N - K) C_MISSING - E log EXTRAS_EXPECTED        (found, missing, E extras)
               + prior(D_a) + label nats of the pairs

with J_a the inertia tensor of the paired preop nodes. The number of pairs is decided by this evidence, not by
min(N, M). Under a fixed sigma the best pairing for a correction is a linear assignment in which every preop
node may go unpaired (cost C_MISSING) and every intraop node may be extra (cost C_EXTRA(m)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from snreg import geometry
from snreg.registration._problem import Problem

__all__ = ["Candidate", "squared_distances", "pair_nats", "extra_nats", "assign", "evaluate", "score_many",
           "refine_many", "sigma_weights", "SIGMA_GRID_MM", "MIN_PAIRS"]

MIN_PAIRS = 3
PI_FOUND = 0.9                    # a SPECT node is found (and stored) during surgery
EXTRAS_EXPECTED = 1.5             # removed nodes that are not on the SPECT, per case
EXTRA_VOLUME_MM3 = 150.0 * 100.0 * 150.0   # the pelvic lymph-node region (width x depth x height)
EXTRA_NEAR_FRACTION = 0.9         # extras in the same station as a SPECT node, rather than anywhere
EXTRA_SPREAD_MM = 10.0            # their offset from that node, per axis
SIGMA_GRID_MM = np.geomspace(2.0, 40.0, 32)   # support of the log-uniform prior on the intraop error sigma
ASSIGN_SIGMAS_MM = (3.0, 6.0, 12.0)          # sigmas at which candidate pairings are assigned
C_FOUND = -np.log(PI_FOUND)
C_MISSING = -np.log(1.0 - PI_FOUND)
_LOG_2PI = np.log(2.0 * np.pi)
_FORBIDDEN = 1e9
_J_FLOOR_MM2 = 25.0               # inertia eigenvalues below this (nearly collinear pairs) are floored


@dataclass(frozen=True)
class Candidate:
    """A partial one-to-one pairing: ``assignment[m]`` is intraop m's preop index or -1 (extra); the correction fitted
    to its pairs, their sum of squared residuals (mm^2) and the score (nats, lower is better)."""

    assignment: np.ndarray
    correction: np.ndarray
    sse: float
    score: float

    @property
    def key(self) -> bytes:
        return self.assignment.astype(np.int16).tobytes()

    @property
    def n_pairs(self) -> int:
        return int(np.sum(self.assignment >= 0))


def _logsumexp(x: np.ndarray, axis: int) -> np.ndarray:
    """log(sum(exp(x))) along ``axis``, stable; scipy's costs 50 times more per call on these small arrays."""
    top = np.max(x, axis=axis, keepdims=True)
    return np.squeeze(top, axis=axis) + np.log(np.sum(np.exp(x - top), axis=axis))


def squared_distances(moved_preop: np.ndarray, intraop: np.ndarray) -> np.ndarray:
    """(..., N, M) squared distances between (moved) preop nodes (..., N, 3) and intraop nodes (M, 3)."""
    diff = moved_preop[..., :, None, :] - intraop
    return np.einsum("...k,...k->...", diff, diff)


def pair_nats(d2: np.ndarray, sigma: float, label_nats: np.ndarray) -> np.ndarray:
    """Cost of each pair at a fixed sigma: Gaussian error of the stored node, found, labels."""
    return d2 / (2.0 * sigma**2) + 1.5 * (_LOG_2PI + 2.0 * np.log(sigma)) + C_FOUND + label_nats


def extra_nats(d2: np.ndarray, sigma) -> np.ndarray:
    """(..., M) cost of each intraop node being extra, given its squared distances (..., N, M) to the mapped preop
    nodes and the error sigma (scalar, or broadcasting against the leading axes): minus the log of the expected
    extra density at its place (module docstring)."""
    n = d2.shape[-2]
    spread2 = EXTRA_SPREAD_MM**2 + np.asarray(sigma, dtype=float) ** 2
    spread2_n = spread2[..., None, None] if np.ndim(spread2) else spread2
    near = (_logsumexp(-d2 / (2.0 * spread2_n), axis=-2) - np.log(n)
            - 1.5 * (_LOG_2PI + np.log(spread2_n[..., 0, :] if np.ndim(spread2) else spread2))
            + np.log(EXTRA_NEAR_FRACTION))
    anywhere = np.log((1.0 - EXTRA_NEAR_FRACTION) / EXTRA_VOLUME_MM3)
    return -(np.logaddexp(near, anywhere) + np.log(EXTRAS_EXPECTED))


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
    d2 = squared_distances(geometry.apply(correction, problem.preop), problem.intraop)
    pair = pair_nats(d2, sigma, problem.label_nats) + (0.0 if adjust is None else adjust)
    return _partial_lsa(pair, extra_nats(d2, sigma))


def _fit(problem: Problem, assignments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kabsch corrections (A, 4, 4) of pairings (A, M) (each with >= 3 pairs) and their residuals (A,) mm^2."""
    paired = assignments >= 0
    src = problem.preop[np.maximum(assignments, 0)]                     # (A, M, 3)
    corrections = geometry.kabsch(src, np.broadcast_to(problem.intraop, src.shape), paired.astype(float))
    residual = src @ np.swapaxes(corrections[:, :3, :3], 1, 2) + corrections[:, None, :3, 3] - problem.intraop
    return corrections, np.einsum("amk,amk,am->a", residual, residual, paired)


def score_many(problem: Problem, assignments: np.ndarray) -> list[Candidate]:
    """Fit and score pairings (A, M), each with at least :data:`MIN_PAIRS` pairs (module docstring)."""
    assignments = np.asarray(assignments, dtype=int).reshape(-1, len(problem.intraop))
    corrections, sse = _fit(problem, assignments)
    paired = assignments >= 0
    k = paired.sum(axis=1)
    d2 = squared_distances(_moved(problem, corrections), problem.intraop)          # (A, N, M)
    extra = extra_nats(d2[:, None], SIGMA_GRID_MM[None, :])                         # (A, G, M)
    per_sigma = _fit_terms(sse, k) + np.where(paired[:, None, :], 0.0, extra).sum(axis=2)
    fit = -(_logsumexp(-per_sigma, axis=1) - np.log(len(SIGMA_GRID_MM)))
    outliers = found_nats(k, len(problem.preop))
    rows, cols = np.nonzero(paired)
    labels = np.zeros(len(assignments))
    np.add.at(labels, rows, problem.label_nats[assignments[rows, cols], cols])
    scores = fit + _occam_nats(problem, assignments) + outliers + problem.prior_nats(corrections) + labels
    return [Candidate(a.copy(), c, float(e), float(s)) for a, c, e, s in zip(assignments, corrections, sse, scores)]


def found_nats(k: np.ndarray, n: int) -> np.ndarray:
    """Nats of K of the N preop nodes being found (the rest missing)."""
    return k * C_FOUND + (n - k) * C_MISSING


def evaluate(problem: Problem, assignment: np.ndarray) -> Candidate | None:
    """Fit (Kabsch) and score one pairing; None when it has fewer than :data:`MIN_PAIRS` pairs."""
    if np.sum(assignment >= 0) < MIN_PAIRS:
        return None
    return score_many(problem, assignment[None])[0]


def refine_many(problem: Problem, corrections: np.ndarray, sigmas, adjusts: np.ndarray | None = None,
                iterations: int = 8) -> list[Candidate]:
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
        d2 = squared_distances(_moved(problem, corrections[index]), problem.intraop)
        pair = pair_nats(d2, sigmas[index][:, None, None], problem.label_nats)
        if adjusts is not None:
            pair = pair + adjusts[index]
        updated = np.array([_partial_lsa(p, e) for p, e in zip(pair, extra_nats(d2, sigmas[index]))])
        too_few = (updated >= 0).sum(axis=1) < MIN_PAIRS            # keep the last pairing that had enough
        valid[index[too_few & (assignments[index] == -2).all(axis=1)]] = False
        settled = too_few | np.all(updated == assignments[index], axis=1)
        assignments[index[~too_few]] = updated[~too_few]
        active[index[settled]] = False
        moving = index[~settled]
        corrections[moving], _ = _fit(problem, assignments[moving])
    return score_many(problem, assignments[valid]) if valid.any() else []


def sigma_weights(sse: float, n_pairs: int) -> np.ndarray:
    """Posterior weights of :data:`SIGMA_GRID_MM` (log-uniform prior) given a fit's residual and its pair count."""
    log_like = -_fit_terms(np.asarray([sse], float), np.asarray([n_pairs]))[0]
    return np.exp(log_like - _logsumexp(log_like, axis=0))


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
