"""Per-node confidence: the posterior probability that each intraop node's claim is right (docs/design.md, Contracts).

A claim is the hot spot (preop index) a node came from, or -1 for "from no imaged hot spot". Candidate pairings (the
global search's refined ones and the local moves around the best, each refitted and scored by
:mod:`snreg.registration._model`) are weighted by exp(-score / SCORE_TEMPERATURE). Under each candidate a node's
source is known when the candidate makes it a hot spot's own node, and spread over the hot spots (and "none") by the
extra density when it makes it an extra (:func:`~snreg.registration._model.source_posterior`); the mixture over the
candidates is the node's source posterior. A claim of hot spot j is right when the node came from j (as its own node
or as an extra beside it); a claim of -1 is right for any extra, so its confidence is the posterior weight of the
candidates that make the node extra.
"""

from __future__ import annotations

import numpy as np

from snreg.registration._model import Candidate, source_posterior
from snreg.registration._problem import Problem

__all__ = ["posterior_weights", "source_probabilities", "claim_confidence", "SCORE_TEMPERATURE"]

# Score differences are divided by this before the claims are weighed, to allow for what the model and the search leave
# out: the candidates are a handful of the pairings, and at high noise the ones not found hold real weight (issue 20's
# note). The target-error bounds weigh the candidates as the model says (temperature 1).
SCORE_TEMPERATURE = 2.0
_NEGLIGIBLE = 1e-4                # candidates weighing less change no claim's confidence by more than a few thousandths


def posterior_weights(candidates: list[Candidate], temperature: float = 1.0) -> tuple[list[Candidate], np.ndarray]:
    """The distinct candidates (the best score per pairing, best first) and their normalised posterior weights, score
    differences divided by ``temperature``."""
    unique: dict[bytes, Candidate] = {}
    for cand in candidates:
        if cand.key not in unique or cand.score < unique[cand.key].score:
            unique[cand.key] = cand
    cands = sorted(unique.values(), key=lambda c: c.score)
    scores = np.array([c.score for c in cands])
    weights = np.exp(-(scores - scores.min()) / temperature)
    return cands, weights / weights.sum()


def source_probabilities(problem: Problem, candidates: list[Candidate]) -> tuple[np.ndarray, np.ndarray]:
    """((M, N + 1) probability that intraop m came from hot spot n, column N: from none; (M,) probability that m is
    an extra) over the candidates weighed at :data:`SCORE_TEMPERATURE`."""
    candidates, weights = posterior_weights(candidates, SCORE_TEMPERATURE)
    kept = [(c, w) for c, w in zip(candidates, weights) if w > _NEGLIGIBLE]
    sources = sum(w * source_posterior(problem, c) for c, w in kept)
    extra = sum(w * (c.assignment < 0) for c, w in kept)
    return sources, np.asarray(extra, dtype=float)


def claim_confidence(pairing: np.ndarray, sources: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """(M,) probability that each claim in ``pairing`` (hot spot index or -1) is right."""
    pairing = np.asarray(pairing, dtype=int)
    claimed = sources[np.arange(len(pairing)), np.maximum(pairing, 0)]
    return np.clip(np.where(pairing >= 0, claimed, extra), 0.0, 1.0)
