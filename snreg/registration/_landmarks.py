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

__all__ = ["Landmarks", "landmark_pairs", "SUSPECT_QUANTILE"]

SUSPECT_QUANTILE = 0.999      # a landmark whose leave-one-out residual lies beyond this quantile is suspect
MAX_LANDMARKS = 20


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


def _points(side: str, value) -> dict[str, np.ndarray]:
    """{name: (3,) mm} from a mapping or a node set whose ids are the names; ValueError in one sentence otherwise."""
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
        name = str(name).strip()
        if not name:
            raise ValueError(f"{side}_landmarks: every landmark needs a name (e.g. 'aortic bifurcation')")
        try:
            point = np.asarray(xyz, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            point = np.zeros(0)
        if point.shape != (3,) or not np.all(np.isfinite(point)):
            raise ValueError(f"{side}_landmarks: {name!r} needs a finite (3,) position in mm")
        if name in points:
            raise ValueError(f"{side}_landmarks: {name!r} is given twice; each landmark name once")
        points[name] = point
    if len(points) > MAX_LANDMARKS:
        raise ValueError(f"{side}_landmarks: at most {MAX_LANDMARKS} landmarks, got {len(points)}")
    return points


def landmark_pairs(preop_landmarks, intraop_landmarks, sd_mm: float, initial: np.ndarray) -> Landmarks | None:
    """The landmarks named on both sides, in name order, the preop ones moved by ``initial``; None when none pair."""
    preop, intraop = _points("preop", preop_landmarks), _points("intraop", intraop_landmarks)
    if not preop and not intraop:
        return None
    try:
        sd = float(sd_mm)
    except (TypeError, ValueError):
        sd = float("nan")
    if not (np.isfinite(sd) and 0.0 < sd <= 100.0):
        raise ValueError(f"landmark_sd_mm must be a number of mm above 0 and at most 100, got {sd_mm!r}")
    names = tuple(sorted(set(preop) & set(intraop)))
    unpaired = tuple(sorted(set(preop) ^ set(intraop)))
    if not names:
        return Landmarks((), np.zeros((0, 3)), np.zeros((0, 3)), sd, unpaired)
    moved = np.array([preop[n] for n in names]) @ initial[:3, :3].T + initial[:3, 3]
    return Landmarks(names, moved, np.array([intraop[n] for n in names]), sd, unpaired)
