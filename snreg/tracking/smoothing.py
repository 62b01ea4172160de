"""Smoothing, outlier rejection and the "held still" test over a short window of probe fixes.

The thesis stored a node as the median of 60 frames while the probe rested on it
(§5.2); :func:`summarise` gives that median with its spread, and :class:`FixFilter`
says when the probe is being held still so a node can be stored (or auto-stored).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["FixFilter", "FilterState", "Summary", "summarise"]


@dataclass(frozen=True)
class Summary:
    """Median tip position (mm) of a run of fixes, its spread (RMS distance to the median) and count."""

    xyz: np.ndarray
    spread_mm: float
    n_frames: int


def summarise(points: np.ndarray) -> Summary:
    """Median and spread of positions (n, 3); ValueError when there are none."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) == 0:
        raise ValueError("no valid probe positions to summarise")
    median = np.median(points, axis=0)
    spread = float(np.sqrt(np.mean(np.sum((points - median) ** 2, axis=1))))
    return Summary(median, spread, len(points))


@dataclass(frozen=True)
class FilterState:
    smoothed: np.ndarray | None   # median of the accepted window, mm
    accepted: bool                # was the last fix kept?
    still: bool                   # held still over the still window?
    spread_mm: float              # spread of the still window


class FixFilter:
    """Median smoothing with outlier rejection, and a held-still detector.

    A fix farther than ``outlier_mm`` from the window median is rejected, unless
    ``reset_after`` fixes in a row are: then the probe has really moved and the window
    restarts. The probe is "still" when the last ``still_frames`` accepted fixes lie
    within ``still_mm`` (RMS) of their median.
    """

    def __init__(self, window: int = 9, outlier_mm: float = 6.0, reset_after: int = 5,
                 still_frames: int = 30, still_mm: float = 1.0):
        self.window, self.outlier_mm, self.reset_after = window, outlier_mm, reset_after
        self.still_frames, self.still_mm = still_frames, still_mm
        self._recent: deque[np.ndarray] = deque(maxlen=max(window, still_frames))
        self._rejected = 0

    def reset(self) -> None:
        self._recent.clear()
        self._rejected = 0

    def push(self, xyz: np.ndarray | None) -> FilterState:
        """Feed one fix (None when the frame had none) and get the filter's state."""
        accepted = False
        if xyz is not None:
            xyz = np.asarray(xyz, dtype=float)
            median = self._median()
            if median is None or np.linalg.norm(xyz - median) <= self.outlier_mm:
                accepted, self._rejected = True, 0
            else:
                self._rejected += 1
                if self._rejected >= self.reset_after:
                    self.reset()
                    accepted = True
            if accepted:
                self._recent.append(xyz)
        still, spread = False, float("nan")
        if len(self._recent) >= self.still_frames:
            summary = summarise(np.array(self._recent)[-self.still_frames:])
            spread, still = summary.spread_mm, summary.spread_mm <= self.still_mm
        return FilterState(self._median(), accepted, still, spread)

    def _median(self) -> np.ndarray | None:
        if not self._recent:
            return None
        return np.median(np.array(self._recent)[-self.window:], axis=0)
