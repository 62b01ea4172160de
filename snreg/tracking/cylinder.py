"""The probe's axis fitted to its visible surface, a cylinder of known radius (the ``sgbm`` tracking method)."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

__all__ = ["onto_cylinder"]


def onto_cylinder(axis_points: np.ndarray, surface: np.ndarray, radius: float) -> np.ndarray:
    """The stripe points ``axis_points`` (k, 3) moved onto the axis that puts the SGBM ``surface`` points (n, 3) one
    probe ``radius`` (mm) from it (robust least squares): the ``sgbm`` method's depth and lateral position come from
    the probe's visible surface, while the stripes keep their positions along the axis."""
    if len(axis_points) < 2:
        return axis_points
    centre = axis_points.mean(axis=0)
    direction = np.linalg.svd(axis_points - centre)[2][0]
    e1 = np.cross(direction, [0.0, 0.0, 1.0] if abs(direction[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(direction, e1)

    def line(params):
        c = centre + params[0] * e1 + params[1] * e2
        u = direction + params[2] * e1 + params[3] * e2
        return c, u / np.linalg.norm(u)

    def residual(params):
        c, u = line(params)
        rel = surface - c
        return np.linalg.norm(rel - (rel @ u)[:, None] * u, axis=1) - radius

    fit = least_squares(residual, np.zeros(4), loss="soft_l1", f_scale=0.5, method="trf")
    c, u = line(fit.x)
    return c + ((axis_points - c) @ u)[:, None] * u
