"""Where extra intraop nodes lie: beside a hot spot's node, or anywhere (the part of the model of
:mod:`snreg.registration._model` that the hot-spot semantics of docs/design.md, Contracts rests on).

An extra is a removed node that is not a hot spot's own node; ``EXTRAS_EXPECTED`` of them per case. With probability
``EXTRA_NEAR_FRACTION`` an extra lies beside the node of one of the N hot spots (any of them alike), else anywhere in
the pelvic lymph-node region (``EXTRA_VOLUME_MM3``). Beside a node, its offset is what the thesis gave its extras
(5-15 mm of either sign per axis, §5.4.2: up to 26 mm, so a node farther than that plus the errors is beyond the hot
spot's reach), or, with probability ``EXTRA_CLOSE_FRACTION``, closer than that (a node stored twice, a neighbour in
the same fat): an isotropic Gaussian of ``EXTRA_SPREAD_MM`` per axis. Where that node is known decides the blur:

- the pairing has the hot spot's own stored node: the offset is measured from it, and only the two nodes'
  independent tracking errors blur it (``EXTRA_FROM_NODE_MM2``, from thesis Table 4); the errors the two nodes share
  (SPECT, deformation, registration) cancel;
- it has none (the node is not removed yet, or was never found): the offset is measured from where the hot spot
  maps, blurred by the intraop error sigma.

Why: the one-to-one rule that called an extra "-1" beside its hot spot was wrong (issue 20); what keeps a hot spot's
own node distinct from the extras beside it is this density, which is both tighter and more distinctive than the
own node's Gaussian at high noise.
"""

from __future__ import annotations

import numpy as np

__all__ = ["logsumexp", "extra_nats", "anchored", "anchored_near_log", "anchored_extra_nats", "ANYWHERE_LOG",
           "EXTRAS_EXPECTED", "EXTRA_NEAR_FRACTION"]

EXTRAS_EXPECTED = 1.5             # removed nodes that are not a hot spot's own node, per case (thesis: 0-3)
EXTRA_VOLUME_MM3 = 150.0 * 100.0 * 150.0   # the pelvic lymph-node region (width x depth x height)
EXTRA_NEAR_FRACTION = 0.9         # extras beside a hot spot's node, rather than anywhere
EXTRA_CLOSE_FRACTION = 0.2        # of those, closer to it than the thesis' 5 mm per axis
EXTRA_SPREAD_MM = 10.0            # the close ones' Gaussian, per axis
EXTRA_FROM_NODE_MM2 = 10.0        # two stored nodes' independent tracking errors, per axis: 2 x (4.0 mm / sqrt 3)^2
ANYWHERE_LOG = float(np.log((1.0 - EXTRA_NEAR_FRACTION) / EXTRA_VOLUME_MM3))
_LOG_2PI = np.log(2.0 * np.pi)
_SHELL_BINS = 12
_SEARCH_SPREAD_MM2 = 108.3        # per axis: the mean square of 5-15 mm, the thesis' offsets


def logsumexp(x: np.ndarray, axis: int) -> np.ndarray:
    """log(sum(exp(x))) along ``axis``, stable; scipy's costs 50 times more per call on these small arrays."""
    top = np.max(x, axis=axis, keepdims=True)
    return np.squeeze(top, axis=axis) + np.log(np.sum(np.exp(x - top), axis=axis))


def _shell_radii() -> np.ndarray:
    """Radii (Q,) standing for the distance between an extra and its node when each coordinate differs by 5-15 mm of
    either sign: Gauss-Legendre over the cube, pooled into equal-weight bins (each weighs 1 / Q)."""
    x, w = np.polynomial.legendre.leggauss(6)
    u, wu = 10.0 + 5.0 * x, w / w.sum()
    grid = np.stack(np.meshgrid(u, u, u, indexing="ij"), -1).reshape(-1, 3)
    weight = np.einsum("i,j,k->ijk", wu, wu, wu).ravel()
    order = np.argsort(np.linalg.norm(grid, axis=1))
    radius, weight = np.linalg.norm(grid, axis=1)[order], weight[order]
    bins = np.minimum((np.cumsum(weight) - 0.5 * weight) * _SHELL_BINS, _SHELL_BINS - 1).astype(int)
    return np.array([np.average(radius[bins == b], weights=weight[bins == b]) for b in range(_SHELL_BINS)])


_SHELL_R = _shell_radii()


def _near_log(d2: np.ndarray, blur2) -> np.ndarray:
    """Log density (1/mm^3) of an extra at squared distance d2 from the place of the node it lies beside, that place
    known up to an isotropic Gaussian blur of variance blur2 per axis (broadcasting). The thesis' offsets are a sum of
    thin shells, each convolved with the blur in closed form."""
    spread2 = EXTRA_SPREAD_MM**2 + blur2
    close = -d2 / (2.0 * spread2) - 1.5 * (_LOG_2PI + np.log(spread2))
    blur2 = np.asarray(blur2 + 1.0)[..., None]
    d = np.sqrt(np.maximum(d2, 1e-6))[..., None]
    shells = (-np.log(_SHELL_BINS * 4.0 * np.pi * _SHELL_R * d) - 0.5 * (_LOG_2PI + np.log(blur2))
              - (d - _SHELL_R) ** 2 / (2.0 * blur2) + np.log(-np.expm1(-2.0 * _SHELL_R * d / blur2)))
    return np.logaddexp(logsumexp(shells, axis=-1) + np.log(1.0 - EXTRA_CLOSE_FRACTION),
                        close + np.log(EXTRA_CLOSE_FRACTION))


def _nats(near: np.ndarray, n: int) -> np.ndarray:
    """Minus the log of the expected extra density, from the log densities ``near`` (..., N, M) beside each node."""
    beside = logsumexp(near, axis=-2) - np.log(n) + np.log(EXTRA_NEAR_FRACTION)
    return -(np.logaddexp(beside, ANYWHERE_LOG) + np.log(EXTRAS_EXPECTED))


def extra_nats(d2: np.ndarray, sigma) -> np.ndarray:
    """(..., M) cost of each intraop node being extra, given its squared distances (..., N, M) to the mapped hot spots
    and the error sigma (scalar, or broadcasting against the leading axes), before any hot spot's own node is known:
    the search's cheap stand-in for the density (a Gaussian of the offsets' spread), which the score then replaces."""
    s2 = np.asarray(sigma, dtype=float) ** 2
    spread2 = _SEARCH_SPREAD_MM2 + (s2[..., None, None] if s2.ndim else s2)
    return _nats(-d2 / (2.0 * spread2) - 1.5 * (_LOG_2PI + np.log(spread2)), d2.shape[-2])


def anchored(intraop: np.ndarray, assignments: np.ndarray, d2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where extras are measured from under pairings (A, M): ((A, N, M) squared distances from each hot spot's anchor
    to each intraop node, (A, N) bool: the anchor is the hot spot's own stored node rather than where it maps), given
    the squared distances d2 (A, N, M) from the mapped hot spots."""
    a_count, n = d2.shape[:2]
    owner = np.full((a_count, n), -1)
    rows, cols = np.nonzero(assignments >= 0)
    owner[rows, assignments[rows, cols]] = cols
    between = np.sum((intraop[:, None] - intraop[None]) ** 2, axis=-1)            # (M, M)
    own = owner >= 0
    return np.where(own[..., None], between[np.maximum(owner, 0)], d2), own


def anchored_near_log(d2: np.ndarray, own: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """(A, G, N, M) log density of an extra beside each hot spot's anchor (:func:`anchored`) at each sigma (G,):
    beside an own node the tracking errors blur the offset, beside a mapped hot spot sigma does."""
    a_count, n, m = d2.shape
    near = np.broadcast_to(_near_log(d2, EXTRA_FROM_NODE_MM2)[:, None], (a_count, len(sigmas), n, m)).copy()
    rows, spots = np.nonzero(~own)
    if len(rows):
        near[rows, :, spots, :] = _near_log(d2[rows, spots][:, None, :], np.asarray(sigmas)[None, :, None] ** 2)
    return near


def anchored_extra_nats(d2: np.ndarray, own: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """(A, G, M) cost of each intraop node being extra under pairings with anchors (:func:`anchored`), per sigma."""
    return _nats(anchored_near_log(d2, own, sigmas), d2.shape[-2])
