"""Anatomical landmarks for the simulation study (issue 29): where they lie in the synthetic cohort's pelvis.

Frame as :mod:`snreg.simulation.cohort` (LPS, mm, origin at the upper border of the pubic symphysis). The positions
are approximate values for an adult male pelvis (the aortic bifurcation at L4 in front of the spine, the common iliac
arteries dividing at the pelvic brim in front of the sacroiliac joints, the internal iliac arteries descending from
there along the side wall), plausible rather than measured, as the cohort's station centres are; each patient's
anatomy differs from them by ``ANATOMY_SD_MM`` per axis. A trial's intraop landmarks lie at the truth plus the
pair's own error (``landmark_sd_mm`` per axis), the preop ones exactly where the CT shows them.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from snreg import geometry
from snreg.landmarks import LANDMARKS

__all__ = ["LANDMARK_POSITIONS_MM", "ANATOMY_SD_MM", "with_landmarks", "landmark_order"]

ANATOMY_SD_MM = 8.0
LANDMARK_POSITIONS_MM = {
    "aortic bifurcation": (0.0, 85.0, 160.0),
    "right common iliac bifurcation": (-40.0, 80.0, 95.0),
    "left common iliac bifurcation": (40.0, 80.0, 95.0),
    "right internal iliac origin": (-45.0, 90.0, 80.0),
    "left internal iliac origin": (45.0, 90.0, 80.0),
    "top of the pubic symphysis": (0.0, 0.0, 0.0),
}


def landmark_order() -> tuple[str, ...]:
    """The landmarks a study of K takes, the first K: spread around the pelvis before close to each other."""
    first = ("aortic bifurcation", "right common iliac bifurcation", "left common iliac bifurcation",
             "top of the pubic symphysis")
    return first + tuple(name for name in LANDMARKS if name not in first)


def with_landmarks(trial, count: int, sd_mm: float, rng: np.random.Generator, swap: bool = False):
    """The trial with ``count`` landmark pairs: preop in the moved frame registration sees, intraop at the truth plus
    the pair's error; with ``swap`` the first two landmarks' intraop names exchanged (a wrong name)."""
    names = landmark_order()[:count]
    anatomy = np.array([LANDMARK_POSITIONS_MM[name] for name in names]) + rng.normal(0.0, ANATOMY_SD_MM, (count, 3))
    intraop = anatomy + rng.normal(0.0, sd_mm, anatomy.shape)
    moved = geometry.apply(geometry.invert(trial.intraop_from_moved), anatomy)
    intraop_names = list(names)
    if swap and count >= 2:
        intraop_names[0], intraop_names[1] = intraop_names[1], intraop_names[0]
    return replace(trial, preop_landmarks=dict(zip(names, moved)), intraop_landmarks=dict(zip(intraop_names, intraop)),
                   landmark_sd_mm=float(sd_mm), swapped=tuple(names[:2]) if swap and count >= 2 else ())
