"""One-to-one assignment, refinement and the score every candidate pairing is judged by.

Model: each paired intraop node is its preop node moved by a rigid correction plus
isotropic Gaussian error of unknown size sigma; extra intraop nodes stay unassigned.
With a Jeffreys prior on sigma integrated out, a pairing ``a`` with K pairs and the
least-squares correction ``D_a`` has the negative log posterior (in nats)

    score(a) = (3K - 6)/2 * log(SSE_a + (3K - 6) * FLOOR_MM**2) + prior(D_a) + labels(a)

(the Laplace term of the rotation fit is the same for every pairing of the same preop
set and drops out). FLOOR_MM keeps a perfect fit from scoring minus infinity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from snreg import geometry
from snreg.registration._problem import Problem

__all__ = ["Candidate", "assign", "constraint", "fit", "evaluate", "refine_many", "squared_distances", "FLOOR_MM"]

FLOOR_MM = 1.0
_FORBIDDEN = 1e9


@dataclass(frozen=True)
class Candidate:
    """A one-to-one pairing: ``assignment[m]`` is intraop m's preop index or -1 (unassigned)."""

    assignment: np.ndarray
    correction: np.ndarray
    sse: float
    score: float

    @property
    def key(self) -> bytes:
        return self.assignment.astype(np.int16).tobytes()


def squared_distances(moved_preop: np.ndarray, intraop: np.ndarray) -> np.ndarray:
    """(N, M) squared distances between (moved) preop and intraop nodes."""
    return ((moved_preop[:, None, :] - intraop[None, :, :]) ** 2).sum(axis=-1)


def _dof(pairs: int) -> int:
    return max(3 * pairs - 6, 1)


def sigma2_of(sse: float, pairs: int) -> float:
    """Per-axis error variance estimated from a fit's residual, floored at FLOOR_MM**2."""
    return max(sse / _dof(pairs), FLOOR_MM**2)


def constraint(n_preop: int, n_intraop: int, *, pin: tuple[int, int] | None = None,
               leave_out: int | None = None) -> np.ndarray:
    """An (N, M) cost adjustment: ``pin=(n, m)`` forces that pair, ``leave_out=m`` keeps intraop m
    unassigned where the counts allow it."""
    adjust = np.zeros((n_preop, n_intraop))
    if pin is not None:
        adjust[pin] = -_FORBIDDEN
    if leave_out is not None:
        adjust[:, leave_out] = _FORBIDDEN
    return adjust


def _lsa(cost: np.ndarray) -> np.ndarray:
    rows, cols = linear_sum_assignment(cost)
    assignment = np.full(cost.shape[1], -1, dtype=int)
    assignment[cols] = rows
    return assignment


def _moved(problem: Problem, corrections: np.ndarray) -> np.ndarray:
    """Preop nodes under each correction: (A, N, 3) for corrections (A, 4, 4)."""
    return problem.preop @ np.swapaxes(corrections[:, :3, :3], 1, 2) + corrections[:, None, :3, 3]


def assign(problem: Problem, correction: np.ndarray, sigma2: float, adjust: np.ndarray | None = None) -> np.ndarray:
    """One-to-one assignment under ``correction`` minimising squared distance / (2 sigma^2) + label nats.

    The rectangular problem pairs min(N, M) nodes; the rest of the intraop nodes stay -1.
    ``adjust`` (see :func:`constraint`) is added to the cost.
    """
    cost = squared_distances(geometry.apply(correction, problem.preop), problem.intraop) / (2.0 * sigma2)
    cost = cost + problem.label_nats + (0.0 if adjust is None else adjust)
    return _lsa(cost)


def _fit_many(problem: Problem, assignments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kabsch corrections (A, 4, 4) and SSEs (A,) for pairings (A, M) with equal pair counts."""
    rows, cols = np.nonzero(assignments >= 0)
    k = len(cols) // len(assignments)
    src = problem.preop[assignments[rows, cols]].reshape(len(assignments), k, 3)
    dst = problem.intraop[cols].reshape(len(assignments), k, 3)
    corrections = geometry.kabsch(src, dst)
    residual = src @ np.swapaxes(corrections[:, :3, :3], 1, 2) + corrections[:, None, :3, 3] - dst
    return corrections, (residual**2).sum(axis=(1, 2))


def fit(problem: Problem, assignment: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares correction (Kabsch) for a pairing, and its sum of squared residuals."""
    corrections, sse = _fit_many(problem, assignment[None])
    return corrections[0], float(sse[0])


def _scores(problem: Problem, assignments: np.ndarray, corrections: np.ndarray, sse: np.ndarray) -> np.ndarray:
    dof = _dof(int(np.sum(assignments[0] >= 0)))
    rows, cols = np.nonzero(assignments >= 0)
    labels = np.zeros(len(assignments))
    np.add.at(labels, rows, problem.label_nats[assignments[rows, cols], cols])
    return 0.5 * dof * np.log(sse + dof * FLOOR_MM**2) + problem.prior_nats(corrections) + labels


def evaluate(problem: Problem, assignment: np.ndarray) -> Candidate:
    """Fit and score one pairing (see the module docstring)."""
    corrections, sse = _fit_many(problem, assignment[None])
    score = _scores(problem, assignment[None], corrections, sse)
    return Candidate(assignment.copy(), corrections[0], float(sse[0]), float(score[0]))


def refine_many(problem: Problem, corrections: np.ndarray, sigma2: np.ndarray, adjusts: np.ndarray | None = None,
                iterations: int = 6) -> list[Candidate]:
    """Alternate one-to-one assignment and Kabsch from each start correction (A, 4, 4).

    ``sigma2`` (A,) weighs distance against labels; ``adjusts`` (A, N, M) constrain each
    run (see :func:`constraint`). A fixed number of rounds keeps every run in one batch.
    """
    corrections = np.asarray(corrections)
    sigma2 = np.broadcast_to(np.asarray(sigma2, dtype=float), (len(corrections),))
    extra = problem.label_nats if adjusts is None else problem.label_nats + adjusts
    assignments = None
    for _ in range(iterations):
        d2 = ((_moved(problem, corrections)[:, :, None, :] - problem.intraop[None, None]) ** 2).sum(axis=-1)
        cost = d2 / (2.0 * sigma2[:, None, None]) + extra
        updated = np.array([_lsa(c) for c in cost])
        if assignments is not None and np.array_equal(updated, assignments):
            break
        assignments = updated
        corrections, sse = _fit_many(problem, assignments)
        sigma2 = np.maximum(sse / _dof(int(np.sum(assignments[0] >= 0))), FLOOR_MM**2)
    scores = _scores(problem, assignments, corrections, sse)
    return [Candidate(a, c, float(e), float(s)) for a, c, e, s in zip(assignments, corrections, sse, scores)]
