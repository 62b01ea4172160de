"""Stripe-marker segmentation in one image (thesis §3.4): colour thresholds from the probe model.

Detection runs on a downscaled copy (fast), then each stripe is segmented again at full
resolution inside a padded box. Stripes are the largest colour blobs that lie close to
one another; they are ordered along the probe axis in the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from snreg.probe import ProbeModel

__all__ = ["Stripes", "find_stripes", "stripe_mask", "DETECT_SCALE"]

DETECT_SCALE = 0.25
_MIN_AREA_PX = 6           # at DETECT_SCALE


@dataclass(frozen=True)
class Stripes:
    """Stripes found in one image, full-resolution pixel coordinates.

    ``centroids`` (k, 2) and ``areas`` (k,) ordered along ``direction`` (unit 2-vector along
    the probe axis in the image); ``labels`` marks stripe k's pixels with k + 1 inside ``box``
    (x0, y0, x1, y1).
    """

    centroids: np.ndarray
    areas: np.ndarray
    direction: np.ndarray
    labels: np.ndarray
    box: tuple[int, int, int, int]

    def __len__(self) -> int:
        return len(self.centroids)


def stripe_mask(image_bgr: np.ndarray, probe: ProbeModel) -> np.ndarray:
    """uint8 mask (255 = stripe colour) of a BGR image, opened to drop speckle."""
    hsv = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV)
    mask = cv2.inRange(hsv, np.array(probe.hsv_low, np.uint8), np.array(probe.hsv_high, np.uint8))
    return cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((2, 2), np.uint8))


def _coarse_boxes(image_bgr: np.ndarray, probe: ProbeModel, expected: int) -> list[tuple[int, int, int, int]]:
    small = cv2.resize(image_bgr, None, fx=DETECT_SCALE, fy=DETECT_SCALE, interpolation=cv2.INTER_AREA)
    n, _, stats, centroids = cv2.connectedComponentsWithStats(stripe_mask(small, probe), connectivity=8)
    blobs = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= _MIN_AREA_PX]
    if not blobs:
        return []
    blobs.sort(key=lambda k: -stats[k, cv2.CC_STAT_AREA])
    lead = blobs[0]
    size = max(stats[lead, cv2.CC_STAT_WIDTH], stats[lead, cv2.CC_STAT_HEIGHT])
    near = [k for k in blobs if np.linalg.norm(centroids[k] - centroids[lead]) <= 8 * size
            and stats[k, cv2.CC_STAT_AREA] >= 0.15 * stats[lead, cv2.CC_STAT_AREA]][:expected]
    scale = 1.0 / DETECT_SCALE
    return [(int(stats[k, 0] * scale), int(stats[k, 1] * scale),
             int((stats[k, 0] + stats[k, 2]) * scale), int((stats[k, 1] + stats[k, 3]) * scale)) for k in near]


def find_stripes(image_bgr: np.ndarray, probe: ProbeModel, search_box: tuple[int, int, int, int] | None = None) -> Stripes | None:
    """The probe's stripes in an image, or None when no stripe colour is found.

    ``search_box`` (x0, y0, x1, y1) limits the search (e.g. the band of the other eye).
    """
    height, width = image_bgr.shape[:2]
    ox, oy = 0, 0
    if search_box is not None:
        x0, y0, x1, y1 = (int(v) for v in search_box)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        if x1 - x0 < 8 or y1 - y0 < 8:
            return None
        image_bgr, ox, oy = image_bgr[y0:y1, x0:x1], x0, y0
    boxes = _coarse_boxes(image_bgr, probe, len(probe.stripe_centres_mm))
    if not boxes:
        return None
    pad = int(2 / DETECT_SCALE)
    x0 = max(min(b[0] for b in boxes) - pad, 0)
    y0 = max(min(b[1] for b in boxes) - pad, 0)
    x1 = min(max(b[2] for b in boxes) + pad, image_bgr.shape[1])
    y1 = min(max(b[3] for b in boxes) + pad, image_bgr.shape[0])
    mask = stripe_mask(image_bgr[y0:y1, x0:x1], probe)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8)
    keep = sorted(range(1, n), key=lambda k: -stats[k, cv2.CC_STAT_AREA])[:len(probe.stripe_centres_mm)]
    keep = [k for k in keep if stats[k, cv2.CC_STAT_AREA] >= 0.15 * stats[keep[0], cv2.CC_STAT_AREA]]
    cents = centroids[keep] + np.array([x0 + ox, y0 + oy])
    areas = stats[keep, cv2.CC_STAT_AREA].astype(float)
    if len(keep) >= 2:
        ys, xs = np.nonzero(np.isin(labels, keep))
        pts = np.column_stack([xs, ys]).astype(float)
        _, _, vt = np.linalg.svd(pts - pts.mean(axis=0), full_matrices=False)
        direction = vt[0]
    else:
        direction = np.array([1.0, 0.0])
    order = np.argsort(cents @ direction)
    relabel = np.zeros(n, dtype=np.int32)
    for rank, k in enumerate(np.array(keep)[order]):
        relabel[k] = rank + 1
    return Stripes(cents[order], areas[order], direction, relabel[labels],
                   (x0 + ox, y0 + oy, x1 + ox, y1 + oy))
