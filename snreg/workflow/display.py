"""Frames as the screens show them: RGB at a fraction of the camera resolution, made in the worker thread.

Why here: the acquisition worker and the trocar wizard's capture loop both hand the GUI frames ready to paint,
and the overlays they compute must use the same scale as the images.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["DISPLAY_SCALE", "display_rgb"]

DISPLAY_SCALE = 0.5          # feeds are shown at this fraction of the camera resolution: less work on the GUI thread


def display_rgb(bgr: np.ndarray) -> np.ndarray:
    """A BGR frame as the feeds show it: RGB at :data:`DISPLAY_SCALE`."""
    small = cv2.resize(bgr, None, fx=DISPLAY_SCALE, fy=DISPLAY_SCALE, interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_BGR2RGB)
