"""Per-node confidence: the posterior probability that each intraop node's reported pairing is right.

Candidates (alternative pairings, each refitted) are weighted by exp(-score / SCORE_TEMPERATURE) and the
weights of those that agree with the reported pairing for node m are summed.
"""

from __future__ import annotations

import numpy as np

from snreg import geometry
from snreg.registration._assignment import Candidate, constraint, refine_many, sigma2_of, squared_distances
from snreg.registration._problem import Problem
from snreg.registration.pairing import pair

__all__ = ["posterior_confidence", "alternatives", "SCORE_TEMPERATURE"]

ALTERNATIVES_PER_NODE = 3
# Score differences are divided by this before weighting: the model (free extra nodes,
# isotropic Gaussian error) is sharper than reality; fitted on held-out simulation runs (README).
SCORE_TEMPERATURE = 2.0


def alternatives(problem: Problem, best: Candidate, reported: np.ndarray, per_node: int = ALTERNATIVES_PER_NODE) -> list[Candidate]:
    """For every intraop node, refitted pairings that change its reported partner.

    Node m is pinned in turn to each of its ``per_node`` nearest other preop nodes, and
    (when assigned) left out; each pairing is then refitted. These are the rivals that
    the posterior confidence weighs against the reported pairing.
    """
    n_pre, n_intra = problem.label_nats.shape
    sigma2 = sigma2_of(best.sse, int(np.sum(best.assignment >= 0)))
    d2 = squared_distances(geometry.apply(best.correction, problem.preop), problem.intraop)
    adjusts = []
    for m in range(n_intra):
        others = [int(n) for n in np.argsort(d2[:, m]) if n != reported[m]][:per_node]
        adjusts += [constraint(n_pre, n_intra, pin=(n, m)) for n in others]
        if best.assignment[m] >= 0 and n_intra > n_pre:
            adjusts.append(constraint(n_pre, n_intra, leave_out=m))
    starts = np.repeat(best.correction[None], len(adjusts), axis=0)
    return refine_many(problem, starts, sigma2, np.array(adjusts), iterations=3)


def posterior_confidence(problem: Problem, reported: np.ndarray, candidates: list[Candidate]) -> np.ndarray:
    """Per-node posterior probability that ``reported`` is right, over distinct ``candidates``.

    Each candidate is a hypothesis of the truth: its one-to-one pairing under its own
    refitted correction, left-over nodes read as in the ``assignment`` rule. A reported
    pairing (of any rule or method) earns the weight of the hypotheses that agree with it.
    """
    unique: dict[bytes, Candidate] = {}
    for cand in candidates:
        if cand.key not in unique or cand.score < unique[cand.key].score:
            unique[cand.key] = cand
    cands = list(unique.values())
    scores = np.array([c.score for c in cands])
    weights = np.exp(-(scores - scores.min()) / SCORE_TEMPERATURE)
    weights /= weights.sum()
    agree = np.zeros(len(reported))
    for cand, weight in zip(cands, weights):
        sigma2 = sigma2_of(cand.sse, int(np.sum(cand.assignment >= 0)))
        agree += weight * (pair("assignment", problem, cand.correction, cand.assignment, sigma2) == reported)
    return np.clip(agree, 0.0, 1.0)
