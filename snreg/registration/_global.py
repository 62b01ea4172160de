"""``global``: our correspondence-hypothesis search over partial pairings, the default method.

1. Hypotheses: every preop triplet (the largest-area ones when there are too many) against every ordered intraop
   triplet, each laid on the other at once, and with landmarks (:mod:`snreg.registration._landmarks`) the landmark
   pairs completed by node pairs to three points; those whose correction leaves the rotation/translation bounds, or
   that cross left/right labels, are dropped, and a robust residual keeps the most promising few hundred.
2. The rest are ranked by a quick score: each intraop node pairs with its nearest preop node or is extra,
   whichever costs less under the model of :mod:`snreg.registration._model`, at the best of a few sigmas.
3. The best hypotheses with distinct nearest-neighbour patterns are refined at several sigmas by alternating the
   partial assignment (pairs, missing preop nodes, extra intraop nodes) and Kabsch, and scored.
4. Local moves on the best (an intraop node made extra or paired elsewhere, a preop node left missing) are
   refitted; while one scores better it becomes the best.
5. Refined pairings whose correction leaves the bounds are dropped: when none is left, or when a pairing beyond the
   bounds fits far better than the best inside them (by ``_OUTSIDE_MARGIN_NATS``, the bounds' prior aside), the
   bounds are wrong for these nodes and :class:`NoFitError` says so rather than return a forced fit.
"""

from __future__ import annotations

from itertools import combinations, permutations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial.transform import Rotation

from snreg import geometry
from snreg.errors import NoFitError, TooFewPairsError
from snreg.labels import SIDE_CROSSING_NATS
from snreg.registration._bounded import tilted_within
from snreg.registration._extras import extra_nats
from snreg.registration._model import (ASSIGN_SIGMAS_MM, C_MISSING, MIN_PAIRS, Candidate, pair_nats, refine_many,
                                       squared_distances)
from snreg.registration._problem import Problem, option_count

__all__ = ["solve_global", "local_moves", "no_fit_message", "few_pairs_message"]

_FORBIDDEN = 1e9
_LOCAL_ROUNDS = 2
_LOOSE_SIGMA_MM = 30.0        # assignment sigma when none of ASSIGN_SIGMAS_MM keeps 3 pairs
_LEANING = 1.5                # triplet fits this far past a bound are pulled onto it as starting points; farther, dropped
_SCREENED = 400               # hypotheses kept by the robust residual for the quick score
_SCREEN_MM = 20.0             # its cap: a node farther than this from every mapped preop node counts as this far
_SCREENED_OUTSIDE = 100       # hypotheses beyond the bounds given a quick score
_REFINED_OUTSIDE = 3          # and refined
_OUTSIDE_MARGIN_NATS = 15.0   # a fit beyond the bounds this much better (a million to one) refuses the best inside


def _triangle_area(points: np.ndarray) -> np.ndarray:
    return 0.5 * np.linalg.norm(np.cross(points[..., 1, :] - points[..., 0, :], points[..., 2, :] - points[..., 0, :]), axis=-1)


def _frames(triangles: np.ndarray) -> np.ndarray:
    """(H, 3, 3) orthonormal frames (columns) of triangles (H, 3, 3): along the first side, in the plane, normal."""
    first = triangles[:, 1] - triangles[:, 0]
    second = triangles[:, 2] - triangles[:, 0]
    e1 = first / np.maximum(np.linalg.norm(first, axis=1, keepdims=True), 1e-9)
    normal = np.cross(first, second)
    e3 = normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-9)
    return np.stack([e1, np.cross(e3, e1), e3], axis=2)


def _triangle_transforms(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(H, 4, 4) rigid transforms laying each source triangle (H, 3, 3) on its target triangle: frames aligned,
    centroids matched. Exact for congruent triangles and a hypothesis otherwise (the refinement fits properly);
    ten times cheaper than batched Kabsch on thousands of triplets."""
    rotation = _frames(target) @ np.swapaxes(_frames(source), 1, 2)
    return geometry.make_transform(rotation, target.mean(axis=1) - np.einsum("hij,hj->hi", rotation, source.mean(axis=1)))


def _hypotheses(problem: Problem, max_hypotheses: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Preop triplets (P, 3) and ordered intraop triplets (I, 3) to pair, all against all (none with fewer than 3
    nodes on a side)."""
    n, m = len(problem.preop), len(problem.intraop)
    if n < 3 or m < 3:
        return np.zeros((0, 3), dtype=int), np.zeros((0, 3), dtype=int)
    intra = np.array(list(permutations(range(m), 3)), dtype=int)
    if len(intra) > max_hypotheses:
        intra = intra[np.sort(rng.choice(len(intra), max_hypotheses, replace=False))]
    pre = np.array(list(combinations(range(n), 3)), dtype=int)
    keep = max(1, max_hypotheses // len(intra))
    if len(pre) > keep:
        pre = pre[np.argsort(-_triangle_area(problem.preop[pre]), kind="stable")[:keep]]
    return pre, intra


def few_pairs_message(problem: Problem) -> str:
    """Why no three nodes pair without crossing left/right labels: how many stored nodes can pair with a hot spot of
    their side at most (a one-to-one matching), and what to do."""
    allowed = problem.label_nats < SIDE_CROSSING_NATS
    rows, cols = linear_sum_assignment(allowed, maximize=True)
    most = int(allowed[rows, cols].sum())
    m = len(problem.intraop)
    if most == 0:
        return (f"none of the {m} stored nodes has a hot spot on its side: check the L/R labels of both node sets")
    return (f"the left/right labels let only {most} of the {m} stored nodes pair with a hot spot of their side "
            f"(one each), and a registration needs {MIN_PAIRS}: store a node on the other side, or check the L/R "
            "labels of both node sets")


def _node_triplets(problem: Problem, max_hypotheses: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Corrections (H, 4, 4) laying preop node triplets on intraop node triplets, and their label nats (H,); those
    crossing left/right labels left out."""
    pre, intra = _hypotheses(problem, max_hypotheses, rng)
    pre_idx = np.repeat(pre, len(intra), axis=0)
    intra_idx = np.tile(intra, (len(pre), 1))
    keep = problem.label_nats[pre_idx, intra_idx].max(axis=1) < SIDE_CROSSING_NATS if len(pre_idx) else np.zeros(0, bool)
    if len(pre_idx) and not keep.any() and problem.n_landmarks == 0:
        raise TooFewPairsError(few_pairs_message(problem))
    corrections = _triangle_transforms(problem.preop[pre_idx[keep]], problem.intraop[intra_idx[keep]])
    return corrections, problem.label_nats[pre_idx[keep], intra_idx[keep]].sum(axis=1)


def _landmark_hypotheses(problem: Problem, max_hypotheses: int) -> tuple[np.ndarray, np.ndarray]:
    """Corrections (H, 4, 4) from the landmark pairs, completed by node pairs to three points when fewer than three:
    all landmarks (three or more), both with each node pair (two), the one with each two node pairs (one); with
    their label nats (H,)."""
    marks, n, m = problem.landmarks, len(problem.preop), len(problem.intraop)
    if problem.n_landmarks == 0:
        return np.zeros((0, 4, 4)), np.zeros(0)
    if len(marks) >= 3:
        return geometry.kabsch(marks.preop, marks.intraop)[None], np.zeros(1)
    pairs = np.array([(a, b) for a in range(n) for b in range(m)], dtype=int)
    if len(marks) == 2:
        chosen = pairs[:, None, :]                                              # (P, 1, 2): one node pair each
    else:
        firsts, seconds = np.triu_indices(len(pairs), 1)
        both = (pairs[firsts, 0] != pairs[seconds, 0]) & (pairs[firsts, 1] != pairs[seconds, 1])
        chosen = np.stack([pairs[firsts[both]], pairs[seconds[both]]], axis=1)  # (P, 2, 2): two node pairs each
        if len(chosen) > max_hypotheses:
            chosen = chosen[:max_hypotheses]
    labels = problem.label_nats[chosen[..., 0], chosen[..., 1]]
    keep = labels.max(axis=1) < SIDE_CROSSING_NATS
    chosen = chosen[keep]
    source = np.concatenate([np.broadcast_to(marks.preop, (len(chosen),) + marks.preop.shape),
                             problem.preop[chosen[..., 0]]], axis=1)
    target = np.concatenate([np.broadcast_to(marks.intraop, (len(chosen),) + marks.intraop.shape),
                             problem.intraop[chosen[..., 1]]], axis=1)
    return geometry.kabsch(source, target), labels[keep].sum(axis=1)


def landmark_nats(problem: Problem, corrections: np.ndarray) -> np.ndarray:
    """(H,) nats of the landmark pairs' residuals under corrections (H, 4, 4): Gaussian with their own error."""
    if problem.n_landmarks == 0:
        return np.zeros(len(corrections))
    marks = problem.landmarks
    moved = np.einsum("hij,lj->hli", corrections[:, :3, :3], marks.preop) + corrections[:, None, :3, 3]
    return np.sum((moved - marks.intraop) ** 2, axis=(1, 2)) / (2.0 * marks.sd_mm**2)


def no_fit_message(problem: Problem, outside: bool = False) -> str:
    reason = ("the nodes fit far better by a correction beyond them" if outside else "none lies within them")
    labelled = bool(np.any(problem.label_nats))
    if problem.vertical is not None:
        return (f"no pairing of the nodes fits with gravity's start: a tilt within {problem.rotation_bound_deg:g} "
                f"degrees of the two downs and a centroid shift within {problem.max_translation_mm:g} mm ({reason}): "
                "check the table tilt and the patient position, give a rough initial alignment, or widen the bounds")
    return (f"no pairing of the nodes fits within {problem.max_rotation_deg:g} degrees and "
            f"{problem.max_translation_mm:g} mm of the initial alignment ({reason}"
            f"{' that the left/right labels allow' if labelled and not outside else ''}): give a rough initial "
            f"alignment, {'check the labels' if labelled else 'use the anatomical labels'}, or widen the rotation "
            "and translation bounds")


def _screened(problem: Problem, corrections: np.ndarray, triplet_labels: np.ndarray, count: int):
    """The ``count`` hypotheses with the lowest robust residual: the quick score costs more per hypothesis."""
    if len(corrections) <= count:
        return corrections, triplet_labels
    moved = np.einsum("hij,nj->hni", corrections[:, :3, :3], problem.preop) + corrections[:, None, :3, 3]
    nearest = squared_distances(moved, problem.intraop).min(axis=1)                  # (H, M)
    robust = np.minimum(nearest, _SCREEN_MM**2).sum(axis=1) + triplet_labels
    if problem.n_landmarks:            # a landmark pair counts as a node pair would, by its own error
        robust = robust + 2.0 * ASSIGN_SIGMAS_MM[0] ** 2 * landmark_nats(problem, corrections)
    chosen = np.argsort(robust, kind="stable")[:count]
    return corrections[chosen], triplet_labels[chosen]


def _pulled_within(problem: Problem, corrections: np.ndarray) -> np.ndarray:
    """Corrections (H, 4, 4) moved onto the bounds: the rotation vector shortened to the angle bound, the centroid's
    displacement to the translation bound. Starting points for a refinement that keeps its fits within them."""
    if len(corrections) == 0:
        return corrections
    if problem.vertical is not None:                      # from a gravity start only the tilt is bounded
        rotation = tilted_within(corrections[:, :3, :3], problem.vertical, problem.rotation_bound_deg)
    else:
        rotvec = Rotation.from_matrix(corrections[:, :3, :3]).as_rotvec()
        angle = np.linalg.norm(rotvec, axis=1, keepdims=True)
        limit = np.radians(problem.max_rotation_deg)
        rotation = Rotation.from_rotvec(rotvec * np.minimum(1.0, limit / np.maximum(angle, 1e-12))).as_matrix()
    centre = problem.centre
    shift = np.einsum("hij,j->hi", corrections[:, :3, :3], centre) + corrections[:, :3, 3] - centre
    length = np.linalg.norm(shift, axis=1, keepdims=True)
    shift *= np.minimum(1.0, problem.max_translation_mm / np.maximum(length, 1e-12))
    return geometry.make_transform(rotation, centre + shift - np.einsum("hij,j->hi", rotation, centre))


def _best_outside(problem: Problem, corrections: np.ndarray, triplet_labels: np.ndarray) -> float:
    """The best score (without the bounds' prior) of a refined pairing whose correction leaves the bounds, or inf:
    a result inside the bounds that fits far worse than this one is not a fit but the bounds forcing one."""
    if len(corrections) == 0:
        return np.inf
    corrections, triplet_labels = _screened(problem, corrections, triplet_labels, _SCREENED_OUTSIDE)
    quick, _ = _quick_scores(problem, corrections, triplet_labels)
    quick -= problem.prior_nats(corrections)
    starts = corrections[np.argsort(quick, kind="stable")[:_REFINED_OUTSIDE]]
    refined = [c for c in refine_many(problem, starts, ASSIGN_SIGMAS_MM[1], bounded=False)
               if not problem.within_bounds(c.correction)]
    return min((c.score - float(problem.prior_nats(c.correction)) for c in refined), default=np.inf)


def _quick_scores(problem: Problem, corrections: np.ndarray, triplet_labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H,) quick scores and (H, M) nearest-preop patterns (-1: extra) of the hypotheses' corrections (H, 4, 4)."""
    moved = np.einsum("hij,nj->hni", corrections[:, :3, :3], problem.preop) + corrections[:, None, :3, 3]
    d2 = squared_distances(moved, problem.intraop)                       # (H, N, M)
    n = len(problem.preop)
    best = np.full(len(corrections), np.inf)
    patterns = np.zeros((len(corrections), len(problem.intraop)), dtype=int)
    for sigma in ASSIGN_SIGMAS_MM:
        extra = extra_nats(d2, sigma)                                   # (H, M)
        pair = pair_nats(d2, sigma, problem.label_nats)                 # (H, N, M)
        nearest = np.argmin(pair, axis=1)                               # (H, M)
        gain = np.take_along_axis(pair, nearest[:, None, :], axis=1)[:, 0] - C_MISSING - extra
        paired = gain < 0
        score = n * C_MISSING + extra.sum(axis=1) + np.where(paired, gain, 0.0).sum(axis=1) \
            - 3.0 * np.log(2.0 * np.pi * sigma**2)
        better = score < best
        best = np.where(better, score, best)
        patterns[better] = np.where(paired, nearest, -1)[better]
    return best + problem.prior_nats(corrections) + triplet_labels + landmark_nats(problem, corrections), patterns


def solve_global(problem: Problem, *, max_hypotheses: int = 6000, refine_top: int = 12) -> list[Candidate]:
    """Refined candidate pairings within the bounds, best first; :class:`NoFitError` when none fits the bounds."""
    max_hypotheses = option_count("global", "max_hypotheses", max_hypotheses)
    refine_top = option_count("global", "refine_top", refine_top)
    rng = np.random.default_rng(problem.seed)
    corrections, triplet_labels = _node_triplets(problem, max_hypotheses, rng)
    if problem.n_landmarks:
        marked, marked_labels = _landmark_hypotheses(problem, max_hypotheses)
        corrections = np.concatenate([corrections.reshape(-1, 4, 4), marked])
        triplet_labels = np.concatenate([triplet_labels, marked_labels])
    if len(corrections) == 0:
        raise TooFewPairsError(few_pairs_message(problem))
    inside = problem.within_bounds(corrections)
    outside_best = _best_outside(problem, corrections[~inside], triplet_labels[~inside])
    angle, shift = problem.correction_size(corrections)
    leaning = ~inside & (angle <= _LEANING * problem.rotation_bound_deg) & (shift <= _LEANING * problem.max_translation_mm)
    if not (inside | leaning).any():              # a few very noisy nodes: every triplet fit leans far
        leaning = ~inside
    corrections[leaning] = _pulled_within(problem, corrections[leaning])   # a noisy triplet may lean past a bound
    corrections, triplet_labels = _screened(problem, corrections[inside | leaning], triplet_labels[inside | leaning],
                                            _SCREENED)

    quick, patterns = _quick_scores(problem, corrections, triplet_labels)
    order = np.argsort(quick, kind="stable")
    _, first = np.unique(patterns[order], axis=0, return_index=True)
    chosen = order[np.sort(first)[:refine_top]]

    sigmas = np.tile(ASSIGN_SIGMAS_MM, len(chosen))
    starts = np.repeat(corrections[chosen], len(ASSIGN_SIGMAS_MM), axis=0)
    candidates: dict[bytes, Candidate] = {}
    refined = refine_many(problem, starts, sigmas)
    if not refined:               # so noisy that no assignment keeps 3 pairs at these sigmas: assign more loosely
        refined = refine_many(problem, corrections[chosen], _LOOSE_SIGMA_MM)
    for cand in refined:
        if cand.key not in candidates or cand.score < candidates[cand.key].score:
            candidates[cand.key] = cand
    if not candidates:
        raise NoFitError(no_fit_message(problem))
    best = min(candidates.values(), key=lambda c: c.score)
    if outside_best + _OUTSIDE_MARGIN_NATS < best.score:
        raise NoFitError(no_fit_message(problem, outside=True))
    for _ in range(_LOCAL_ROUNDS):                # hill-climb by single moves; the moves also feed the confidence
        for cand in local_moves(problem, best):
            if cand.key not in candidates or cand.score < candidates[cand.key].score:
                candidates[cand.key] = cand
        improved = min(candidates.values(), key=lambda c: c.score)
        if improved.key == best.key:
            break
        best = improved
    return sorted(candidates.values(), key=lambda c: c.score)


def local_moves(problem: Problem, best: Candidate, per_node: int = 2) -> list[Candidate]:
    """Refitted pairings one move away from ``best``, within the bounds: each intraop node paired with each of its
    ``per_node`` nearest other preop nodes or made extra, each paired preop node left missing."""
    n, m = len(problem.preop), len(problem.intraop)
    d2 = squared_distances(geometry.apply(best.correction, problem.preop), problem.intraop)
    adjusts = []
    for j in range(m):
        for k in [int(k) for k in np.argsort(d2[:, j]) if k != best.assignment[j]][:per_node]:
            adjusts.append(np.zeros((n, m)))
            adjusts[-1][k, j] = -_FORBIDDEN                   # j paired with k
        if best.assignment[j] >= 0:
            adjusts.append(np.zeros((n, m)))
            adjusts[-1][:, j] = _FORBIDDEN                    # j extra
            adjusts.append(np.zeros((n, m)))
            adjusts[-1][best.assignment[j], :] = _FORBIDDEN   # its preop node missing
    sigma = float(np.sqrt(max(best.sse / max(3 * best.n_pairs - 6, 1), 1.0)))
    starts = np.repeat(best.correction[None], len(adjusts), axis=0)
    return refine_many(problem, starts, sigma, np.array(adjusts), iterations=4)
