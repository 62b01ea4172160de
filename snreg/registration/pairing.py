"""Pairing rules: the hot spot (preop node) each intraop node came from, given a fitted correction (docs/design.md, Contracts).

Every rule reports the same semantics: ``pairing[m]`` is the hot spot intraop node m came from, or -1 for "from no
imaged hot spot"; several nodes may name the same hot spot (``shares``). Rules (``RegistrationResult.pairing`` uses
the one each method names; ``pairings`` holds all of them for comparison):

- ``"hot_spot"``: the most probable source under the model of :mod:`snreg.registration._model`: each hot spot has
  at most one node of its own, other nodes beside it are extras, rarer and 5-15 mm per axis from it, and a node far
  from every hot spot came from none (-1).
- ``"nearest"``: the thesis rule (§3.6.2): every intraop node to its nearest preop node (unlimited reach).
- ``"one_to_one"``: rectangular one-to-one assignment of min(N, M) pairs; nodes left over are -1.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from snreg import geometry
from snreg.registration._model import Candidate, assign, source_posterior, squared_distances
from snreg.registration._problem import Problem, make_problem

__all__ = ["RULES", "pair", "most_probable", "shared", "pairing_at"]

RULES = ("hot_spot", "nearest", "one_to_one")


def most_probable(sources: np.ndarray) -> np.ndarray:
    """(M,) the most probable source of each intraop node from its source probabilities (M, N + 1); -1 for none."""
    best = np.argmax(sources, axis=1)
    return np.where(best == sources.shape[1] - 1, -1, best)


def pair(rule: str, problem: Problem, correction: np.ndarray, sources: np.ndarray) -> np.ndarray:
    """The pairing vector (one preop index or -1 per intraop node) under ``rule``; ``sources`` (M, N + 1) are the
    model's source probabilities at ``correction`` (what the ``"hot_spot"`` rule reports)."""
    if rule == "hot_spot":
        return most_probable(sources)
    d2 = squared_distances(geometry.apply(correction, problem.preop), problem.intraop)
    if rule == "nearest":
        return np.argmin(d2 + 1e3 * problem.label_nats, axis=0)
    rows, cols = linear_sum_assignment(d2 + 1e3 * problem.label_nats)
    pairing = np.full(d2.shape[1], -1, dtype=int)
    pairing[cols] = rows
    return pairing


def shared(pairing: np.ndarray) -> np.ndarray:
    """(M,) bool: another intraop node claims the same hot spot."""
    pairing = np.asarray(pairing, dtype=int)
    counts = np.bincount(pairing[pairing >= 0], minlength=1)
    return (pairing >= 0) & (counts[np.maximum(pairing, 0)] > 1)


def pairing_at(preop, intraop, transform: np.ndarray, sigma_mm: float) -> np.ndarray:
    """The ``"hot_spot"`` rule's pairing (M,) when the ``intraop_from_preop`` transform and the error sigma (mm) are
    known rather than fitted: ``snreg simulate``'s model oracle, which separates what the unknown transform costs from
    what the hot-spot labelling costs."""
    problem = make_problem(preop, intraop, initial=transform)
    assignment = assign(problem, np.eye(4), float(sigma_mm))
    known = Candidate(assignment, np.eye(4), float("nan"), float("nan"))
    return most_probable(source_posterior(problem, known, sigma=float(sigma_mm)))
