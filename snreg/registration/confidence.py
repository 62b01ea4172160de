"""Per-node confidence: the posterior probability that each intraop node's claim is right (docs/design.md, Contracts).

A claim is the hot spot (preop index) a node came from, or -1 for "from no imaged hot spot". Candidate pairings (the
global search's refined ones and the local moves around the best, each refitted and scored by
:mod:`snreg.registration._model`) are weighted by exp(-score / temperature). Under each candidate a node's
source is known when the candidate makes it a hot spot's own node, and spread over the hot spots (and "none") by the
extra density when it makes it an extra (:func:`~snreg.registration._model.source_posterior`); the mixture over the
candidates is the node's source posterior. A claim of hot spot j is right when the node came from j (as its own node
or as an extra beside it); a claim of -1 is right for any extra, so its confidence is the posterior weight of the
candidates that make the node extra.

The candidates are weighed with their score differences divided by a temperature (:func:`claim_temperature`): the
search scores a handful of the pairings, and at high noise the ones it did not find hold real weight, so there the
differences are halved (temperature 2); at the noise of a phantom or a careful case (the best fit's error at most
``NOISE_MM[0]`` per axis) the handful holds nearly all the weight and the model's own weights stand (temperature 1).
Measured per claim over the synthetic cohort and the demo phantom (issue 36's note): halved everywhere, claims the
model put at 0.86 were right 99 % of the time after three phantom nodes; the model's own weights at sigma 15-20 mm made
claims >= 0.95 right only 92-94 % of the time.
"""

from __future__ import annotations

import numpy as np

from snreg.registration._model import Candidate, candidate_sigmas, source_posterior
from snreg.registration._problem import Problem

__all__ = ["posterior_weights", "source_probabilities", "claim_confidence", "claim_temperature", "SCORE_TEMPERATURE",
           "NOISE_MM"]

# Score differences are divided by this before the pairing rule weighs the candidates (issue 20's note); the claims'
# confidence uses claim_temperature; the target-error bounds weigh the candidates as the model says (temperature 1).
SCORE_TEMPERATURE = 2.0
NOISE_MM = (5.0, 10.0)            # the best fit's median error per axis from which the claims' temperature rises to 2
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


def claim_temperature(problem: Problem, best: Candidate) -> float:
    """The temperature the claims' confidence weighs the candidates at: 1 while the best fit's median error per axis
    (its posterior over the error's scale, each node's own covariance included) is at most ``NOISE_MM[0]``, rising
    linearly to :data:`SCORE_TEMPERATURE` at ``NOISE_MM[1]`` (module docstring)."""
    sigmas, weights = candidate_sigmas(problem, best)
    median = float(sigmas[min(int(np.searchsorted(np.cumsum(weights), 0.5)), len(sigmas) - 1)])
    low, high = NOISE_MM
    return 1.0 + (SCORE_TEMPERATURE - 1.0) * float(np.clip((median - low) / (high - low), 0.0, 1.0))


def source_probabilities(problem: Problem, candidates: list[Candidate],
                         temperature: float = SCORE_TEMPERATURE) -> tuple[np.ndarray, np.ndarray]:
    """((M, N + 1) probability that intraop m came from hot spot n, column N: from none; (M,) probability that m is
    an extra) over the candidates weighed at ``temperature``."""
    candidates, weights = posterior_weights(candidates, temperature)
    kept = [(c, w) for c, w in zip(candidates, weights) if w > _NEGLIGIBLE]
    sources = sum(w * source_posterior(problem, c) for c, w in kept)
    extra = sum(w * (c.assignment < 0) for c, w in kept)
    return sources, np.asarray(extra, dtype=float)


def claim_confidence(pairing: np.ndarray, sources: np.ndarray, extra: np.ndarray) -> np.ndarray:
    """(M,) probability that each claim in ``pairing`` (hot spot index or -1) is right."""
    pairing = np.asarray(pairing, dtype=int)
    claimed = sources[np.arange(len(pairing)), np.maximum(pairing, 0)]
    return np.clip(np.where(pairing >= 0, claimed, extra), 0.0, 1.0)
