"""How uncertain a held insertion is: the insertion kept from the last tracked pair while the view is lost.

Why: while the insertion is lost each pair is mapped with the last insertion tracked. The IMU sees every turn of the
camera but not a pure slide, so the longer the view is lost and the more the camera has turned since, the further it
may have slid unseen; a held insertion that kept its last sd would claim a precision nobody measured. Its sd grows as::

    sd^2 = sd_last^2 + (UNSEEN_SLIDE_MM_PER_S * t)^2 + (UNSEEN_SLIDE_MM_PER_DEG * angle)^2

with ``t`` the seconds since the last tracked pair and ``angle`` the IMU's turn since it (degrees). The constants: the
thesis' change of the camera's distance per pose while it is not tracked (Table 3's spread over orientations,
:data:`~snreg.chain.THESIS_TROCAR_CAMERA_SD_MM`, 0.74 mm) is what the camera is taken to have slid unseen once it has
been lost for :data:`MOVED_AFTER_S` (2 s, long enough for a slide) or has turned :data:`MOVED_TURN_DEG` (1 degree:
a surgeon's turn of the scope, which a slide usually goes with): 0.37 mm per second and 0.74 mm per degree. The store
guard takes the camera to have moved exactly when the unseen part passes that per-pose figure
(:func:`may_have_moved`), so one model says both how far the held insertion may be off and when a store must wait.
"""

from __future__ import annotations

import numpy as np

from snreg.chain import THESIS_TROCAR_CAMERA_SD_MM

__all__ = ["MOVED_TURN_DEG", "MOVED_AFTER_S", "MOVED_SD_MM", "UNSEEN_SLIDE_MM_PER_S", "UNSEEN_SLIDE_MM_PER_DEG",
           "unseen_slide_sd_mm", "held_sd_mm", "may_have_moved"]

MOVED_TURN_DEG = 1.0      # the IMU turned this much since the last tracked pair (and nothing else): the camera moved
MOVED_AFTER_S = 2.0       # lost this long (and still): it may have slid unseen
MOVED_SD_MM = THESIS_TROCAR_CAMERA_SD_MM      # an unseen slide of one per-pose sd: moved
UNSEEN_SLIDE_MM_PER_S = MOVED_SD_MM / MOVED_AFTER_S
UNSEEN_SLIDE_MM_PER_DEG = MOVED_SD_MM / MOVED_TURN_DEG


def unseen_slide_sd_mm(lost_s: float, turned_deg: float) -> float:
    """The sd (mm) of the slide the camera may have made unseen in ``lost_s`` seconds while turning ``turned_deg``
    degrees (negative times, from clocks that stepped back, count as none)."""
    return float(np.hypot(UNSEEN_SLIDE_MM_PER_S * max(float(lost_s), 0.0),
                          UNSEEN_SLIDE_MM_PER_DEG * abs(float(turned_deg))))


def held_sd_mm(last_sd_mm: float, lost_s: float, turned_deg: float) -> float:
    """The sd (mm) of an insertion held from a pair tracked with ``last_sd_mm``, ``lost_s`` seconds and
    ``turned_deg`` degrees of the IMU's turn ago (module docstring)."""
    return float(np.hypot(float(last_sd_mm), unseen_slide_sd_mm(lost_s, turned_deg)))


def may_have_moved(lost_s: float, turned_deg: float) -> bool:
    """Whether the camera may have slid since its insertion was last tracked: the unseen slide's sd is over
    :data:`MOVED_SD_MM` (lost over 2 s while still, turned over 1 degree at once, or a mix of both)."""
    return unseen_slide_sd_mm(lost_s, turned_deg) > MOVED_SD_MM
