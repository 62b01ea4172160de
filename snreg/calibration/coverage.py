"""Where the captured checkerboard views cover the image, and whether a new view adds anything.

Why: a stereo calibration is only as good as its views are varied (thesis §4.2 took 30): corners
should reach every part of each image, including the borders where lens distortion is strongest,
and a view that repeats an earlier one adds time but no information. The calibration wizard shows
:func:`coverage_map` as a heat map per eye, warns with :func:`similar_view`, and auto-captures a view
when :func:`is_still` says the board is held still in a new place.

Tolerances are fractions of the image diagonal, so they mean the same at any resolution.

>>> coverage = coverage_map([corners_view1, corners_view2], (960, 540))
>>> coverage.counts.shape, coverage.fraction_covered      # ((9, 16), 0.18)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Coverage", "coverage_map", "mean_corner_shift", "similar_view", "is_still",
           "SIMILAR_SHIFT_FRACTION", "STILL_SHIFT_FRACTION"]

SIMILAR_SHIFT_FRACTION = 0.04   # views whose corners moved less than 4 % of the image diagonal are "the same view"
STILL_SHIFT_FRACTION = 0.002    # a board whose corners move less than 0.2 % of the diagonal per frame is "held still"


@dataclass(frozen=True)
class Coverage:
    """Captured corners per cell of a coarse grid over the image.

    ``counts`` (rows, cols) int: corners of all views falling in each cell, row 0 at the image top;
    ``image_size`` (width, height) px.
    """

    counts: np.ndarray
    image_size: tuple[int, int]

    @property
    def fraction_covered(self) -> float:
        """Share of the cells holding at least one captured corner, 0..1."""
        return float(np.count_nonzero(self.counts) / self.counts.size)


def coverage_map(corner_sets: Sequence[np.ndarray], image_size: tuple[int, int], *,
                 cells_across: int = 16) -> Coverage:
    """Count the corners of every view, each an (N, 2) array of pixel (x, y), per grid cell.

    The grid has ``cells_across`` columns and as many rows as keep the cells about square
    (16 x 9 for a 16:9 image). Corners outside the image are ignored.
    """
    width, height = (int(v) for v in image_size)
    if width <= 0 or height <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if cells_across < 1:
        raise ValueError(f"cells_across must be at least 1, got {cells_across}")
    rows = max(1, round(cells_across * height / width))
    points = [np.asarray(c, dtype=float).reshape(-1, 2) for c in corner_sets]
    xy = np.concatenate(points) if points else np.empty((0, 2))
    counts, _, _ = np.histogram2d(xy[:, 1], xy[:, 0], bins=(rows, cells_across), range=((0, height), (0, width)))
    return Coverage(counts.astype(int), (width, height))


def mean_corner_shift(a: np.ndarray, b: np.ndarray) -> float:
    """Mean distance (px) between corresponding corners of two detections of one board, each (N, 2)."""
    a, b = np.asarray(a, dtype=float).reshape(-1, 2), np.asarray(b, dtype=float).reshape(-1, 2)
    if a.shape != b.shape:
        raise ValueError(f"detections of one board must have equal corner counts, got {len(a)} and {len(b)}")
    return float(np.linalg.norm(a - b, axis=1).mean())


def similar_view(corners: np.ndarray, earlier: Sequence[np.ndarray], image_size: tuple[int, int], *,
                 fraction: float = SIMILAR_SHIFT_FRACTION) -> int | None:
    """Index of the earlier view nearest to ``corners`` when it is closer than ``fraction`` of the diagonal, else None.

    Views are compared by :func:`mean_corner_shift`; pass both eyes' corners stacked to compare stereo views.
    """
    if len(earlier) == 0:
        return None
    shifts = [mean_corner_shift(corners, view) for view in earlier]
    nearest = int(np.argmin(shifts))
    return nearest if shifts[nearest] < fraction * float(np.hypot(*image_size)) else None


def is_still(recent: Sequence[np.ndarray | None], image_size: tuple[int, int], *,
             fraction: float = STILL_SHIFT_FRACTION) -> bool:
    """Whether the board was found in every one of the ``recent`` detections (at least 2, oldest first)
    and no corner set moved by more than ``fraction`` of the image diagonal from one to the next."""
    if len(recent) < 2 or any(c is None for c in recent):
        return False
    tolerance = fraction * float(np.hypot(*image_size))
    return all(mean_corner_shift(a, b) < tolerance for a, b in zip(recent[:-1], recent[1:]))
