"""How a node's own expected error reads on screen: "±9.8" mm, the longest semi-axis of its 90 % error ellipsoid.

Why one place: the acquisition's and the review's node tables show the same figure under the same caption and
explanation, from the covariance each stored node carries (:mod:`snreg.tracking.uncertainty`).
"""

from __future__ import annotations

import math

from snreg.tracking.uncertainty import ellipsoid_radius_mm

__all__ = ["ERROR_CAPTION", "ERROR_TIP", "error_text"]

ERROR_CAPTION = "±90 %"          # the review's table adds "(mm)" as its other captions do
ERROR_TIP = ("the node's own expected error: the longest semi-axis of its 90 % error ellipsoid, mm (its true position "
             "lies within this of the stored one, 9 times in 10, in its least certain direction; from the stereo "
             "geometry, the tracker, the probe's pointing, the IMU and the chain); empty when not stored")


def error_text(covariance) -> str:
    """"±9.8" (mm, 90 %) for a node's covariance (3, 3) mm^2; "" when it is unknown (NaN, or None)."""
    radius = math.nan if covariance is None else ellipsoid_radius_mm(covariance)
    return "" if math.isnan(radius) else f"\u00b1{radius:.1f}"
