"""Pairing rules: which preop node each intraop node is paired with, given a fitted correction.

Rules (``RegistrationResult.pairing`` uses the one each method names):

- ``"nearest"``: the thesis rule (§3.6.2): every intraop node to its nearest preop node.
- ``"one_to_one"``: rectangular one-to-one assignment; nodes left over are -1 (extras).
- ``"assignment"``: one-to-one, then each left-over node joins its nearest preop node when
  within ``DUPLICATE_GATE_SIGMAS`` fitted error sigmas (an extra node removed from the same
  SPECT hot spot), else -1. Chosen from ``snreg simulate`` measurements (see README).
"""

from __future__ import annotations

import numpy as np

from snreg import geometry
from snreg.registration._assignment import squared_distances
from snreg.registration._problem import Problem

__all__ = ["RULES", "pair", "DUPLICATE_GATE_SIGMAS"]

RULES = ("nearest", "one_to_one", "assignment")
DUPLICATE_GATE_SIGMAS = 3.0


def pair(rule: str, problem: Problem, correction: np.ndarray, assignment: np.ndarray, sigma2: float) -> np.ndarray:
    """The pairing vector (one preop index or -1 per intraop node) under ``rule``."""
    d2 = squared_distances(geometry.apply(correction, problem.preop), problem.intraop)
    nearest = np.argmin(d2 + problem.label_nats * 2.0 * sigma2, axis=0)
    if rule == "nearest":
        return nearest
    pairing = assignment.copy()
    if rule == "assignment":
        leftover = np.flatnonzero(pairing < 0)
        gate2 = (DUPLICATE_GATE_SIGMAS**2) * 3.0 * sigma2
        close = d2[nearest[leftover], leftover] <= gate2
        pairing[leftover[close]] = nearest[leftover[close]]
    return pairing
