"""Pairing rules: which preop node each intraop node is paired with, given a fitted correction.

Rules (``RegistrationResult.pairing`` uses the one each method names):

- ``"nearest"``: the thesis rule (§3.6.2): every intraop node to its nearest preop node.
- ``"one_to_one"``: rectangular one-to-one assignment of min(N, M) pairs; nodes left over are -1.
- ``"assignment"``: the partial one-to-one pairing of the model (:mod:`snreg.registration._model`): a node is
  paired only when that is more likely than its being extra and its preop node's being missing, so the number of
  pairs follows the evidence. An intraop node judged extra is -1 even when it lies near a preop node.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from snreg import geometry
from snreg.registration._model import assign, squared_distances
from snreg.registration._problem import Problem, make_problem

__all__ = ["RULES", "pair", "pairing_at"]

RULES = ("nearest", "one_to_one", "assignment")


def pair(rule: str, problem: Problem, correction: np.ndarray, assignment: np.ndarray) -> np.ndarray:
    """The pairing vector (one preop index or -1 per intraop node) under ``rule``; ``assignment`` is the model's
    partial pairing at ``correction`` (what the ``"assignment"`` rule reports)."""
    if rule == "assignment":
        return assignment.copy()
    d2 = squared_distances(geometry.apply(correction, problem.preop), problem.intraop)
    if rule == "nearest":
        return np.argmin(d2 + 1e3 * problem.label_nats, axis=0)
    rows, cols = linear_sum_assignment(d2 + 1e3 * problem.label_nats)
    pairing = np.full(d2.shape[1], -1, dtype=int)
    pairing[cols] = rows
    return pairing


def pairing_at(preop, intraop, transform: np.ndarray, sigma_mm: float) -> np.ndarray:
    """The ``"assignment"`` rule's pairing (M,) when the ``intraop_from_preop`` transform and the error sigma (mm) are
    known rather than fitted: ``snreg simulate``'s model oracle, which separates what the unknown transform costs from
    what DESIGN §4's pairing costs (an extra nearer a node than the true one takes the pair whatever the transform)."""
    problem = make_problem(preop, intraop, initial=transform)
    return assign(problem, np.eye(4), float(sigma_mm))
