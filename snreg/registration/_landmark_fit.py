"""Which landmark pairs to trust, and how well each agrees with the rest once registered.

Why: a landmark pair's correspondence is taken as known, so a wrong one (a name given to the wrong vessel, a
bifurcation that moved) pulls every node with it. Each pair is therefore either right, with its own Gaussian error,
or wrong (prior ``WRONG_PRIOR``), lying anywhere in the pelvic region; the registration is run on the landmark sets
that leave out up to two pairs, and the set whose posterior is highest (its search's best score plus what leaving
those out costs) is the one registered. The pairs left out are ``landmarks_suspect``; every pair's residual and
leave-one-out residual are reported, so no landmark is trusted silently.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from itertools import combinations
from typing import TypeVar

import numpy as np

from snreg import geometry
from snreg.registration._extras import EXTRA_VOLUME_MM3
from snreg.registration._landmarks import Landmarks
from snreg.registration._model import Candidate, fit_pairs, unmodelled_grid
from snreg.registration._problem import Problem

__all__ = ["trusted_landmarks", "landmark_residuals", "checkable", "WRONG_PRIOR"]

WRONG_PRIOR = 0.05                 # a landmark pair is wrong (name, or the vessel moved)
_MAX_LEFT_OUT = 2
_WRONG_NATS = float(np.log(EXTRA_VOLUME_MM3) - np.log(WRONG_PRIOR))      # a wrong pair: anywhere, and its prior
_RIGHT_NATS = float(-np.log(1.0 - WRONG_PRIOR))
_Fit = TypeVar("_Fit")


def _without(problem: Problem, left_out: tuple[int, ...]) -> Problem:
    """The problem with the landmark pairs at ``left_out`` removed."""
    marks = problem.landmarks
    keep = [k for k in range(len(marks)) if k not in left_out]
    return replace(problem, landmarks=Landmarks(tuple(marks.names[k] for k in keep), marks.preop[keep],
                                                marks.intraop[keep], marks.sd_mm, marks.unpaired))


def trusted_landmarks(problem: Problem, solve: Callable[[Problem], _Fit]) -> tuple[_Fit, tuple[str, ...]]:
    """The fit (``solve``'s, of a problem with some landmark pairs left out; it carries its ``score`` in nats) of the
    landmark pairs the nodes and the other pairs most probably say are right, and the names left out (the suspects).
    ``solve`` raises ValueError for a set too small to register; such sets are skipped. Without landmark pairs, the
    problem's own fit."""
    marks = problem.landmarks
    if not problem.n_landmarks:
        return solve(problem), ()
    best = None
    for size in range(0, min(_MAX_LEFT_OUT, len(marks)) + 1):
        for left_out in combinations(range(len(marks)), size):
            trial = _without(problem, left_out) if left_out else problem
            try:
                fit = solve(trial)
            except ValueError:
                continue
            total = fit.score + size * _WRONG_NATS + (len(marks) - size) * _RIGHT_NATS
            if best is None or total < best[0]:
                best = (total, fit, tuple(marks.names[k] for k in left_out))
    if best is None:                    # every set too small or refused: the full set says why
        return solve(problem), ()
    return best[1], best[2]


def landmark_residuals(problem: Problem, base: Candidate, correction: np.ndarray,
                       every: Landmarks) -> tuple[dict[str, float], dict[str, float]]:
    """({name: residual mm} at ``correction``, {name: residual mm when the others and the nodes alone register}) for
    ``every`` landmark pair (those left out of ``problem`` included); NaN where too few points remain."""
    moved = geometry.apply(correction, every.preop)
    residual = {name: float(np.linalg.norm(m - x)) for name, m, x in zip(every.names, moved, every.intraop)}
    sigma = float(unmodelled_grid(problem)[int(np.argmax(base.fit_weights))]) if base.fit_weights is not None else None
    used = problem.landmarks.names if problem.landmarks is not None else ()
    loo = {}
    for k, name in enumerate(every.names):
        others = tuple(j for j, other in enumerate(used) if other == name)
        alone = _without(problem, others) if others else problem
        if base.n_pairs + alone.n_landmarks < 3:
            loo[name] = float("nan")
            continue
        fitted = fit_pairs(alone, base.assignment, sigma)
        loo[name] = float(np.linalg.norm(geometry.apply(fitted, every.preop[k][None])[0] - every.intraop[k]))
    return residual, loo


def checkable(leave_one_out_mm: dict[str, float]) -> bool:
    """Whether the points can reveal a wrong landmark: some landmark pair's leave-one-out fit is determined (3 points
    remain without it). False for, e.g., 1 node and 2 landmarks (3 points in all); True without landmark pairs."""
    return not leave_one_out_mm or any(np.isfinite(list(leave_one_out_mm.values())))
