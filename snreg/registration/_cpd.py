"""``cpd``: rigid Coherent Point Drift (Myronenko & Song 2010, Fig. 2), without scaling.

The preop nodes are the centroids of a Gaussian mixture with a uniform outlier term of
weight ``w``; EM moves them rigidly onto the intraop nodes. The variance starts large
(the mean squared distance of all pairs), so with only 3-10 nodes a sizeable ``w``
dominates the Gaussians from the first step and the fit stalls; ``DEFAULT_W`` was chosen
by ``snreg simulate --methods cpd`` over w in {0, 0.01, 0.05, 0.1, 0.2} (docs/method/registration.md). Landmark pairs join each M-step as
pairs of known correspondence with their own variance: weight ``sigma2 / landmark_sd_mm^2`` beside a posterior's 1
(:func:`~snreg.registration._landmarks.landmark_weight`); sigma2 stays the nodes' own.
"""

from __future__ import annotations

import numpy as np

from snreg import geometry
from snreg.registration._landmarks import landmark_weight
from snreg.registration._model import squared_distances
from snreg.registration._problem import Problem, option_count, option_number

__all__ = ["solve_cpd", "DEFAULT_W"]

DEFAULT_W = 0.0


def solve_cpd(problem: Problem, *, w: float = DEFAULT_W, max_iter: int = 150, tolerance: float = 1e-6) -> np.ndarray:
    """The correction (4, 4) in the initial-aligned frame."""
    w = option_number("cpd", "w", w, low=0.0, high=1.0, high_open=True)
    max_iter = option_count("cpd", "max_iter", max_iter)
    tolerance = option_number("cpd", "tolerance", tolerance, low=0.0, low_open=True)
    x = problem.intraop            # data, (N_x, 3)
    y = problem.preop              # mixture centroids, (M_y, 3)
    marks = problem.landmarks
    mark_x, mark_y = (marks.intraop, marks.preop) if problem.n_landmarks else (np.zeros((0, 3)), np.zeros((0, 3)))
    n_x, m_y, dim = len(x), len(y), 3
    rotation, translation = np.eye(3), np.zeros(3)
    sigma2 = float(squared_distances(y, x).sum() / (dim * n_x * m_y))
    previous = np.inf
    for _ in range(max_iter):
        moved = y @ rotation.T + translation
        d2 = squared_distances(moved, x)                                   # (M_y, N_x)
        gauss = np.exp(-d2 / (2.0 * sigma2))
        outlier = (2.0 * np.pi * sigma2) ** (dim / 2) * w / (1.0 - w) * m_y / n_x
        denom = gauss.sum(axis=0) + outlier
        post = gauss / np.maximum(denom, np.finfo(float).tiny)             # P[m, n]
        n_p = post.sum()
        if n_p < 1e-12:
            break
        # landmark pairs: known partners with their own variance, i.e. weight sigma2 / sd^2 beside a posterior's 1
        lw = np.full(len(mark_x), landmark_weight(problem, sigma2)) if len(mark_x) else np.zeros(0)
        total = n_p + lw.sum()
        mu_x = (post.sum(axis=0) @ x + lw @ mark_x) / total
        mu_y = (post.sum(axis=1) @ y + lw @ mark_y) / total
        x_hat, y_hat = x - mu_x, y - mu_y
        a_nodes = x_hat.T @ post.T @ y_hat
        a = a_nodes + ((mark_x - mu_x).T * lw) @ (mark_y - mu_y) if len(mark_x) else a_nodes
        u, _, vt = np.linalg.svd(a)
        c = np.diag([1.0, 1.0, np.linalg.det(u @ vt)])
        rotation = u @ c @ vt
        translation = mu_x - rotation @ mu_y
        sigma2 = float((post.sum(axis=0) @ np.sum(x_hat**2, axis=1) - 2.0 * np.trace(a_nodes.T @ rotation)
                        + post.sum(axis=1) @ np.sum(y_hat**2, axis=1)) / (n_p * dim))
        sigma2 = max(sigma2, 1e-6)
        objective = float((post * d2).sum() / (2 * sigma2) + n_p * dim / 2 * np.log(sigma2))
        if abs(previous - objective) <= tolerance * max(abs(objective), 1.0):
            break
        previous = objective
    return geometry.make_transform(rotation, translation)
