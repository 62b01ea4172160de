"""The outlines the node views draw for each node's 90 % error ellipsoid: rings in 3D, shadows in the 2D projections.

Why: a node's covariance (mm^2) says how far and in which direction its true position may lie; the views draw the
ellipsoid holding it 9 times in 10 (:data:`~snreg.tracking.uncertainty.ELLIPSOID_LEVEL`, the same the node tables'
"±mm 90 %" gives the longest semi-axis of). In 3D, its three principal ellipses (rings through two of its axes each);
in a 2D projection, its shadow: the projection of the ellipsoid ``x^T S^-1 x <= k^2`` onto a plane is the ellipse of the
2 x 2 block of S at the same ``k`` (the 3-dof chi-square radius, 2.5 at 90 %). Pure numpy: the views pass the result
to ``setData`` of items made once. Nodes with an unknown covariance (NaN) get no outline.
"""

from __future__ import annotations

import numpy as np

from snreg.tracking.uncertainty import ELLIPSOID_SCALE as SCALE      # semi-axis = SCALE * sd along it

__all__ = ["ellipsoid_rings", "ellipse_shadows"]
_SAMPLES = 36


def _known(centres, covariances) -> tuple[np.ndarray, np.ndarray]:
    """The centres (K, 3) and covariances (K, 3, 3) of the nodes whose covariance is known."""
    centres = np.asarray(centres, dtype=float).reshape(-1, 3)
    if covariances is None or not len(centres):
        return np.zeros((0, 3)), np.zeros((0, 3, 3))
    covariances = np.asarray(covariances, dtype=float).reshape(-1, 3, 3)
    known = np.all(np.isfinite(covariances), axis=(1, 2))
    return centres[known], covariances[known]


def ellipsoid_rings(centres, covariances, samples: int = _SAMPLES) -> np.ndarray:
    """(K * 3 * 2 * samples, 3) mm: line segments (start, end pairs, for a ``mode="lines"`` item) of the three
    principal ellipses of each node's 90 % ellipsoid; ``centres`` (N, 3) mm, ``covariances`` (N, 3, 3) mm^2 or None."""
    centres, covariances = _known(centres, covariances)
    if not len(centres):
        return np.zeros((0, 3))
    values, vectors = np.linalg.eigh(covariances)
    axes = vectors * (SCALE * np.sqrt(np.maximum(values, 0.0)))[:, None, :]          # (K, 3, 3): columns
    angle = np.linspace(0.0, 2.0 * np.pi, samples + 1)
    circle = np.stack([np.cos(angle), np.sin(angle)])                                 # (2, samples + 1)
    rings = []
    for a, b in ((0, 1), (0, 2), (1, 2)):
        points = centres[:, :, None] + axes[:, :, [a, b]] @ circle                    # (K, 3, samples + 1)
        segments = np.stack([points[:, :, :-1], points[:, :, 1:]], axis=-1)           # (K, 3, samples, 2)
        rings.append(np.moveaxis(segments, 1, -1).reshape(len(centres), -1, 3))
    return np.concatenate(rings, axis=1).reshape(-1, 3)


def ellipse_shadows(centres, covariances, h: int, v: int, samples: int = _SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) mm of each node's 90 % ellipsoid outline projected on axes ``h`` (horizontal) and ``v`` (vertical), one
    closed curve per node separated by NaN (for ``connect="finite"``)."""
    centres, covariances = _known(centres, covariances)
    if not len(centres):
        return np.zeros(0), np.zeros(0)
    block = covariances[:, [h, v]][:, :, [h, v]]
    values, vectors = np.linalg.eigh(block)
    axes = vectors * (SCALE * np.sqrt(np.maximum(values, 0.0)))[:, None, :]          # (K, 2, 2)
    angle = np.linspace(0.0, 2.0 * np.pi, samples + 1)
    outline = centres[:, [h, v], None] + axes @ np.stack([np.cos(angle), np.sin(angle)])      # (K, 2, samples + 1)
    gap = np.full((len(centres), 2, 1), np.nan)
    curves = np.concatenate([outline, gap], axis=2)
    return curves[:, 0].ravel(), curves[:, 1].ravel()
