"""Where node labels go on screen and where the camera looks: plain functions on numpy arrays, no widgets.

Why: nodes a few millimetres apart drew their labels on top of each other ("SNSNSN4"), and a node far from the
others fell outside the 3D view. :func:`place_labels` puts each label beside its marker, greedily, at the first of a
fixed list of offsets (growing rings around the marker) where it covers no other label and no marker;
:func:`fit_camera` puts the camera where every node, a far one included, is inside the field of view. Both are
deterministic and are tested directly, since OpenGL may not render where the tests run.

>>> corners = place_labels(anchors_px, sizes_px)             # (N, 2) top-left corners, pixels
>>> corner = place_beside(bounds_px, size_px, obstacles_px)   # one label beside a region, clear of what is drawn
>>> centre, distance = fit_camera(xyz_mm, fov_deg=60, width=800, height=400)
"""

from __future__ import annotations

import numpy as np

__all__ = ["place_labels", "place_beside", "label_boxes", "fit_camera"]

MARKER_PX = 6.0         # half the side of the square a marker is taken to cover
GAP_PX = MARKER_PX + 2  # between a marker's centre and the nearest edge of its label: clear of its own marker
RINGS = 12              # how far out (in label heights) a label may be pushed before it takes the least-covered spot
# Offsets tried in each ring, as (dx, dy) directions: up-right first (the usual place), then the other corners,
# then the sides. Screen y grows downwards.
_DIRECTIONS = ((1, -1), (1, 1), (-1, -1), (-1, 1), (1, 0), (-1, 0), (0, -1), (0, 1))


def _candidate(anchor, size, direction, distance) -> np.ndarray:
    """Top-left corner of a label of ``size`` placed ``distance`` px from ``anchor`` in ``direction``."""
    (x, y), (w, h), (dx, dy) = anchor, size, direction
    left = x + distance if dx > 0 else x - distance - w if dx < 0 else x - w / 2
    top = y + distance if dy > 0 else y - distance - h if dy < 0 else y - h / 2
    return np.array([left, top])


def _overlap(box, boxes: np.ndarray) -> float:
    """Total area of ``box`` (left, top, right, bottom) covered by ``boxes`` (K, 4)."""
    if not len(boxes):
        return 0.0
    w = np.minimum(box[2], boxes[:, 2]) - np.maximum(box[0], boxes[:, 0])
    h = np.minimum(box[3], boxes[:, 3]) - np.maximum(box[1], boxes[:, 1])
    return float(np.sum(np.clip(w, 0, None) * np.clip(h, 0, None)))


def _within(box, area) -> bool:
    """Whether ``box`` (left, top, right, bottom) lies wholly inside ``area``: it then has no part outside, exactly
    (the area less the overlap left rounding errors, so a free spot was not seen as free and every spot was tried)."""
    return bool(box[0] >= area[0] and box[1] >= area[1] and box[2] <= area[2] and box[3] <= area[3])


def label_boxes(corners, sizes) -> np.ndarray:
    """(N, 4) left, top, right, bottom of labels with these top-left ``corners`` and ``sizes`` (N, 2) px."""
    corners, sizes = np.asarray(corners, float).reshape(-1, 2), np.asarray(sizes, float).reshape(-1, 2)
    return np.hstack([corners, corners + sizes])


def place_labels(anchors, sizes, *, gap: float = GAP_PX, marker: float = MARKER_PX, area=None) -> np.ndarray:
    """Top-left corners (N, 2) px for labels of ``sizes`` (N, 2) px beside markers at ``anchors`` (N, 2) px.

    Labels are placed in order; each takes the first spot, ring by ring outwards from ``gap`` px, that covers no
    label already placed and no marker (a square of half-side ``marker`` around every anchor) and, when ``area``
    (width, height) is given, lies inside it. If none is free within :data:`RINGS` rings, the least-covered spot
    is taken. Same input, same output.
    """
    anchors = np.asarray(anchors, float).reshape(-1, 2)
    sizes = np.asarray(sizes, float).reshape(-1, 2)
    markers = np.hstack([anchors - marker, anchors + marker])
    placed = np.zeros((0, 4))
    corners = np.zeros_like(anchors)
    for k, (anchor, size) in enumerate(zip(anchors, sizes)):
        step = max(size[1], 1.0)
        best, best_cost, free = None, np.inf, False
        for ring in range(RINGS):
            for direction in _DIRECTIONS:
                corner = _candidate(anchor, size, direction, gap + ring * step)
                box = np.r_[corner, corner + size]
                outside = area is not None and (box[0] < 0 or box[1] < 0 or box[2] > area[0] or box[3] > area[1])
                covered = _overlap(box, placed) + _overlap(box, markers) + (1e6 if outside else 0.0)
                free = covered == 0.0
                if free or covered + ring < best_cost:
                    best, best_cost = corner, covered + ring
                if free:
                    break
            if free:
                break
        corners[k] = best
        placed = np.vstack([placed, np.r_[best, best + size]])
    return corners


def place_beside(bounds, size, obstacles=(), *, area=None, gap: float = 4.0, rings: int = 6) -> np.ndarray:
    """Top-left corner (2,) px for a label of ``size`` (w, h) px beside a region ``bounds`` (left, top, right, bottom
    px; e.g. a hot spot's ellipse): right of it, left, below, above, then its corners, ring by ring outwards (one
    label height apart, ``rings`` of them), the first spot that covers none of ``obstacles`` (K, 4) boxes (the probe's
    marker and words, labels placed already) and lies inside ``area`` (left, top, right, bottom) when given; else the
    least covered. Why: a hot spot's words were drawn under the probe's depth label when the probe rested beside it."""
    (left, top, right, bottom), (w, h) = np.asarray(bounds, float), np.asarray(size, float)
    obstacles = np.asarray(obstacles, float).reshape(-1, 4)
    inside = None if area is None else np.asarray(area, float).reshape(4)
    mid_x, mid_y = (left + right - w) / 2, (top + bottom - h) / 2
    best, best_cost = None, np.inf
    for ring in range(rings):
        d = gap + ring * max(h, 1.0)
        for x, y in ((right + d, mid_y), (left - d - w, mid_y), (mid_x, bottom + d), (mid_x, top - d - h),
                     (right + d, top - d - h), (left - d - w, top - d - h), (right + d, bottom + d),
                     (left - d - w, bottom + d)):
            box = np.array([x, y, x + w, y + h])
            cost = _overlap(box, obstacles)
            if inside is not None and not _within(box, inside):     # the part outside counts as covered, and more
                cost += 4.0 * (w * h - _overlap(box, inside.reshape(1, 4)))
            if cost == 0.0:
                return box[:2]
            if cost + ring < best_cost:
                best, best_cost = box[:2], cost + ring
    return best


def fit_camera(points, *, fov_deg: float, width: float, height: float, margin: float = 1.15,
               min_radius_mm: float = 25.0) -> tuple[np.ndarray, float]:
    """(centre (3,), distance) for a camera looking at the centre of the bounding box of ``points`` (N, 3) mm so
    that every point is in view from any direction: the bounding sphere, grown by ``margin``, fits inside the
    narrower of the horizontal field ``fov_deg`` (pyqtgraph's ``fov`` is horizontal) and the vertical field it
    gives at ``width`` x ``height`` px."""
    points = np.asarray(points, float).reshape(-1, 3)
    if not len(points):
        return np.zeros(3), 4.0 * min_radius_mm
    low, high = points.min(axis=0), points.max(axis=0)
    centre = (low + high) / 2
    radius = max(float(np.linalg.norm(points - centre, axis=1).max()), min_radius_mm) * margin
    half_h = np.radians(fov_deg) / 2
    half_v = np.arctan(np.tan(half_h) * max(height, 1.0) / max(width, 1.0))
    return centre, radius / np.sin(min(half_h, half_v))
