"""``global``: our correspondence-hypothesis search, the default method.

1. Hypotheses: every preop triplet (the largest-area ones when there are too many) against
   every ordered intraop triplet, each fitted at once by batched Kabsch.
2. Hypotheses whose correction leaves the rotation/translation bounds, or that cross
   left/right labels, are dropped.
3. The rest are ranked by a quick score (nearest-neighbour residual, prior, labels);
   the best few with distinct nearest-neighbour patterns are refined by alternating
   one-to-one assignment and Kabsch (:func:`~snreg.registration._assignment.refine_many`).
4. The refined pairing with the lowest score (fit, prior, labels) within the bounds wins;
   the runners-up feed the confidence. When noise pushes every fit out of the bounds
   (three nodes, sigma ~ 20 mm), the prior alone ranks them rather than failing.
"""

from __future__ import annotations

from itertools import combinations, permutations

import numpy as np

from snreg import geometry
from snreg.labels import SIDE_CROSSING_NATS
from snreg.registration._assignment import FLOOR_MM, Candidate, refine_many
from snreg.registration._problem import Problem, option_count

__all__ = ["solve_global"]


def _triangle_area(points: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(points[..., 1, :] - points[..., 0, :], points[..., 2, :] - points[..., 0, :]), axis=-1)


def _hypotheses(problem: Problem, max_hypotheses: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Preop triplets (P, 3) and ordered intraop triplets (I, 3) to pair, all against all."""
    n, m = len(problem.preop), len(problem.intraop)
    intra = np.array(list(permutations(range(m), 3)), dtype=int)
    if len(intra) > max_hypotheses:
        intra = intra[np.sort(rng.choice(len(intra), max_hypotheses, replace=False))]
    pre = np.array(list(combinations(range(n), 3)), dtype=int)
    keep = max(1, max_hypotheses // len(intra))
    if len(pre) > keep:
        pre = pre[np.argsort(-_triangle_area(problem.preop[pre]), kind="stable")[:keep]]
    return pre, intra


def solve_global(problem: Problem, *, max_hypotheses: int = 6000, refine_top: int = 16) -> list[Candidate]:
    """Refined candidate pairings, best first. Raises ValueError when no hypothesis fits the bounds."""
    max_hypotheses = option_count("global", "max_hypotheses", max_hypotheses)
    refine_top = option_count("global", "refine_top", refine_top)
    rng = np.random.default_rng(problem.seed)
    pre, intra = _hypotheses(problem, max_hypotheses, rng)
    pre_idx = np.repeat(pre, len(intra), axis=0)
    intra_idx = np.tile(intra, (len(pre), 1))
    keep = problem.label_nats[pre_idx, intra_idx].max(axis=1) < SIDE_CROSSING_NATS
    corrections = geometry.kabsch(problem.preop[pre_idx[keep]], problem.intraop[intra_idx[keep]])
    triplet_labels = problem.label_nats[pre_idx[keep], intra_idx[keep]].sum(axis=1)
    if len(corrections) == 0:
        raise ValueError("every node pairing crosses left/right labels; check the L/R labels of both node sets")
    inside = problem.within_bounds(corrections)
    if inside.any():  # with few, very noisy nodes every exact triplet fit may overshoot: then the prior ranks them
        corrections, triplet_labels = corrections[inside], triplet_labels[inside]

    moved = np.einsum("hij,nj->hni", corrections[:, :3, :3], problem.preop) + corrections[:, None, :3, 3]
    d2 = np.einsum("hnmk,hnmk->hnm", moved[:, :, None, :] - problem.intraop[None, None], moved[:, :, None, :] - problem.intraop[None, None])
    nearest = np.argmin(d2, axis=2)
    n_pairs = min(len(problem.preop), len(problem.intraop))
    dof = max(3 * n_pairs - 6, 1)
    nn_sse = np.sort(d2.min(axis=2), axis=1)[:, :n_pairs].sum(axis=1)
    quick = 0.5 * dof * np.log(nn_sse + dof * FLOOR_MM**2) + problem.prior_nats(corrections) + triplet_labels

    order = np.argsort(quick, kind="stable")
    _, first = np.unique(nearest[order], axis=0, return_index=True)
    chosen = order[np.sort(first)[:refine_top]]

    candidates: dict[bytes, Candidate] = {}
    for cand in refine_many(problem, corrections[chosen], np.maximum(nn_sse[chosen] / dof, FLOOR_MM**2)):
        candidates.setdefault(cand.key, cand)
    ranked = sorted(candidates.values(), key=lambda c: c.score)
    inside = [c for c in ranked if problem.within_bounds(c.correction)]
    return inside + [c for c in ranked if not problem.within_bounds(c.correction)]
