"""Anatomical landmarks in the registration: named points found on the CT and touched in surgery, paired by name.

Why: the thesis' method needs 3 imaged sentinel nodes, and proposes landmarks such as the pelvic arteries, which
deform less than 2.1 mm (thesis §6). A landmark pair's correspondence is known, so it enters every fit as a pair with
its own error (``landmark_sd_mm`` per axis, isotropic); it is never a hot spot and never in a pairing. A landmark
that contradicts the rest (a wrong name, a vessel that moved) must not be trusted silently:
:func:`suspects` tests each pair's leave-one-out residual against what the fit and its own error allow.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from snreg.landmarks import landmark_key, landmark_name
from snreg.registration._covariance import blur_sigmas

__all__ = ["Landmarks", "landmark_pairs", "landmark_weight", "SUSPECT_QUANTILE"]

SUSPECT_QUANTILE = 0.999      # a landmark whose leave-one-out residual lies beyond this quantile is suspect
MAX_LANDMARKS = 20
MIN_NODE_SD_MM = 1.0          # a node is never weighed as more exact than this against a landmark pair


@dataclass(frozen=True, eq=False)
class Landmarks:
    """Landmark pairs: ``names`` (L,), their preop points (L, 3, already moved by the problem's ``initial``) and intraop
    points (L, 3), mm, and their own error ``sd_mm`` per axis; ``unpaired``: names given on one side only."""

    names: tuple[str, ...]
    preop: np.ndarray
    intraop: np.ndarray
    sd_mm: float
    unpaired: tuple[str, ...] = ()

    def __len__(self) -> int:
        return len(self.names)


def _points(side: str, value) -> dict[str, tuple[str, np.ndarray]]:
    """{key: (name, (3,) mm)} from a mapping or a node set whose ids are the names, each name as
    :func:`~snreg.landmarks.landmark_name` keeps it and keyed by :func:`~snreg.landmarks.landmark_key` (the file
    readers' rule, so "Aortic  Bifurcation" pairs with "aortic bifurcation"); ValueError in one sentence otherwise."""
    if value is None:
        return {}
    if isinstance(value, Mapping):
        items = list(value.items())
    elif hasattr(value, "ids") and hasattr(value, "xyz"):
        items = list(zip(value.ids, np.asarray(value.xyz, dtype=float).reshape(-1, 3)))
    else:
        raise ValueError(f"{side}_landmarks must map each landmark's name to its (3,) position in mm, or be a node set "
                         "whose ids are the names")
    points = {}
    for name, xyz in items:
        try:
            name = landmark_name(name)
        except ValueError as error:
            raise ValueError(f"{side}_landmarks: {error}") from None
        try:
            point = np.asarray(xyz, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            point = np.zeros(0)
        if point.shape != (3,) or not np.all(np.isfinite(point)):
            raise ValueError(f"{side}_landmarks: {name!r} needs a finite (3,) position in mm")
        if landmark_key(name) in points:
            raise ValueError(f"{side}_landmarks: {name!r} is given twice; each landmark name once")
        points[landmark_key(name)] = (name, point)
    if len(points) > MAX_LANDMARKS:
        raise ValueError(f"{side}_landmarks: at most {MAX_LANDMARKS} landmarks, got {len(points)}")
    return points


def landmark_pairs(preop_landmarks, intraop_landmarks, sd_mm: float, initial: np.ndarray) -> Landmarks | None:
    """The landmarks named on both sides (names as the preop side spells them), in name order, the preop ones moved by ``initial``; None when none pair."""
    preop, intraop = _points("preop", preop_landmarks), _points("intraop", intraop_landmarks)
    if not preop and not intraop:
        return None
    try:
        sd = float(sd_mm)
    except (TypeError, ValueError):
        sd = float("nan")
    if not (np.isfinite(sd) and 0.0 < sd <= 100.0):
        raise ValueError(f"landmark_sd_mm must be a number of mm above 0 and at most 100, got {sd_mm!r}")
    keys = sorted(set(preop) & set(intraop))
    unpaired = tuple(sorted([preop[k][0] for k in set(preop) - set(intraop)]
                            + [intraop[k][0] for k in set(intraop) - set(preop)]))
    if not keys:
        return Landmarks((), np.zeros((0, 3)), np.zeros((0, 3)), sd, unpaired)
    moved = np.array([preop[k][1] for k in keys]) @ initial[:3, :3].T + initial[:3, 3]
    return Landmarks(tuple(preop[k][0] for k in keys), moved, np.array([intraop[k][1] for k in keys]), sd, unpaired)


def landmark_weight(problem, node_variance_mm2: float) -> float:
    """A landmark pair's weight beside a node's (weight 1) in the fits of icp, cpd and chamfer: the nodes' error
    variance per axis over the pair's own (``landmark_sd_mm`` squared), as the global model weighs them. The nodes'
    variance is the solver's own estimate at its current fit, at least their given covariances' mean variance and
    ``MIN_NODE_SD_MM`` squared (a fit that happens to pass through the nodes does not make the landmarks vanish)."""
    given = float(blur_sigmas(problem, 0.0)) ** 2
    return max(float(node_variance_mm2), given, MIN_NODE_SD_MM**2) / problem.landmarks.sd_mm**2
