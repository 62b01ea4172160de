"""``icp``: point-to-point Iterative Closest Point (Besl & McKay 1992), the thesis' baseline (§2.5).

Every preop (moving) node takes its nearest intraop (fixed) node as partner, Kabsch
fits the rigid correction, and this repeats until the mean squared error stops
changing. Starts from the initial alignment; no global search, as in MATLAB's
``pcregistericp`` that the thesis used. Landmark pairs join every Kabsch fit with their known partners, each weighed
by :func:`~snreg.registration._landmarks.landmark_weight` against the nodes' current residual.
"""

from __future__ import annotations

import numpy as np

from snreg import geometry
from snreg.registration._landmarks import landmark_weight
from snreg.registration._model import squared_distances
from snreg.registration._problem import Problem, option_count, option_number

__all__ = ["solve_icp"]


def solve_icp(problem: Problem, *, max_iter: int = 100, tolerance_mm2: float = 1e-8) -> np.ndarray:
    """The correction (4, 4) in the initial-aligned frame."""
    max_iter = option_count("icp", "max_iter", max_iter)
    tolerance_mm2 = option_number("icp", "tolerance_mm2", tolerance_mm2, low=0.0, low_open=True)
    marks = problem.landmarks if problem.n_landmarks else None
    correction = np.eye(4)
    previous = np.inf
    for _ in range(max_iter):
        d2 = squared_distances(geometry.apply(correction, problem.preop), problem.intraop)
        partner = np.argmin(d2, axis=1)
        node_d2 = d2[np.arange(len(partner)), partner]
        mse = float(node_d2.mean())
        if marks is not None:       # landmark pairs: known partners, weighed against the nodes' current residual
            weight = landmark_weight(problem, mse / 3.0)
            mark_d2 = np.sum((geometry.apply(correction, marks.preop) - marks.intraop) ** 2, axis=1)
            mse = float((node_d2.sum() + weight * mark_d2.sum()) / (len(node_d2) + weight * len(marks)))
        if previous - mse < tolerance_mm2:
            break
        previous = mse
        if marks is None:
            correction = geometry.kabsch(problem.preop, problem.intraop[partner])
        else:
            correction = geometry.kabsch(np.vstack([problem.preop, marks.preop]),
                                         np.vstack([problem.intraop[partner], marks.intraop]),
                                         np.concatenate([np.ones(len(partner)), np.full(len(marks), weight)]))
    return correction
