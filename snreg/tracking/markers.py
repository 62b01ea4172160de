"""Stripe-marker segmentation in one image (thesis §3.4): colour thresholds from the probe model.

Detection runs on a copy reduced to about ``DETECT_WIDTH`` pixels across (fast; full size for
standard-definition images), then each candidate's stripes are segmented again at full resolution
inside a padded box. Blobs that touch the image border are never stripes: they may be cut off, so
their centroid is not the stripe's.

A scene may hold other green things (fiducials, reflections), so the search yields candidate groups
of blobs, best first: the largest blobs that lie close to one another (the probe in a clean view),
then other groups of two or three nearby blobs ranked by how much they look like a row of equal,
evenly spaced bands. The tracker keeps the first that passes its 3D checks
(:mod:`snreg.tracking.plausibility`). Stripes are ordered along the probe axis in the image.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from snreg.probe import ProbeModel

__all__ = ["Stripes", "find_stripes", "find_stripe_candidates", "stripe_mask", "stripe_cut_by_border", "detect_scale",
           "DETECT_WIDTH"]

DETECT_WIDTH = 480          # coarse detection runs at about this many pixels across (1920 px: a quarter)
_MIN_AREA_PX = 6            # at the detection scale
_MAX_BLOBS = 8              # the largest blobs considered for candidate groups
_NEAR_SIZES = 8             # blobs of one group lie within this many lead-blob sizes of the lead
_EDGE_PAD_PX = 10           # segmentation crops are padded this much more, for the stripes' thin edges
_REBUILD_GROWTH = 1.5       # a stripe rebuilt from the colour connected to it grows at most this many times
_SQUARE = np.ones((2, 2), np.uint8)


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


@dataclass(frozen=True)
class _Blob:
    """A coarse blob: bounding box (x0, y0, x1, y1) and centroid in full-resolution pixels, area at detection scale."""

    box: tuple[int, int, int, int]
    centroid: np.ndarray
    area: float
    size: float


def detect_scale(width: int) -> float:
    """The coarse detection scale for images ``width`` pixels across (1 for narrow images)."""
    return min(1.0, DETECT_WIDTH / float(width))


def stripe_mask(image_bgr: np.ndarray, probe: ProbeModel) -> np.ndarray:
    """uint8 mask (255 = stripe colour) of a BGR image, opened to drop speckle."""
    return _open(_stripe_colour(image_bgr, probe))


def _stripe_colour(image_bgr: np.ndarray, probe: ProbeModel) -> np.ndarray:
    """uint8 mask (255) of the pixels within the probe model's stripe colour range."""
    hsv = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV)
    return cv2.inRange(hsv, np.array(probe.hsv_low, np.uint8), np.array(probe.hsv_high, np.uint8))


def _open(mask: np.ndarray) -> np.ndarray:
    """The mask opened by a 2 x 2 square without moving it: OpenCV's opening by an even kernel (one anchor for
    both steps) shifts every blob by a whole pixel right and down, and every centroid with it."""
    return cv2.dilate(cv2.erode(mask, _SQUARE, anchor=(1, 1)), _SQUARE, anchor=(0, 0))


def stripe_cut_by_border(image_bgr: np.ndarray, probe: ProbeModel, band_px: int = 4, min_run_px: int = 6) -> bool:
    """Whether the stripe colour crosses the image's border (over ``min_run_px`` of it, seen in a ``band_px`` band):
    the probe runs out of the view there. A blob touching the border may be cut off, so it is never used
    (:func:`find_stripe_candidates`); a pair without a fix then owes it to the border, whatever the stripes left in
    view showed."""
    bands = (image_bgr[:band_px], image_bgr[-band_px:], image_bgr[:, :band_px], image_bgr[:, -band_px:])
    return any(np.count_nonzero(stripe_mask(np.ascontiguousarray(band), probe)) >= band_px * min_run_px
               for band in bands)


def find_stripes(image_bgr: np.ndarray, probe: ProbeModel, search_box: tuple[int, int, int, int] | None = None) -> Stripes | None:
    """The best candidate of :func:`find_stripe_candidates`, or None when no stripe colour is found."""
    return next(find_stripe_candidates(image_bgr, probe, search_box), None)


def find_stripe_candidates(image_bgr: np.ndarray, probe: ProbeModel,
                           search_box: tuple[int, int, int, int] | None = None) -> Iterator[Stripes]:
    """Candidate stripe groups in an image, best first (module docstring); segmented lazily, one per step.

    ``search_box`` (x0, y0, x1, y1) limits the search (e.g. the band of the other eye); blobs touching the
    border of the whole image are left out either way.
    """
    height, width = image_bgr.shape[:2]
    x0, y0, x1, y1 = 0, 0, width, height
    if search_box is not None:
        x0, y0, x1, y1 = (int(v) for v in search_box)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
        if x1 - x0 < 8 or y1 - y0 < 8:
            return
    scale = detect_scale(width)
    blobs = _coarse_blobs(image_bgr[y0:y1, x0:x1], probe, scale, (x0, y0), (width, height))
    seen = set()
    expected = len(probe.stripe_centres_mm)
    for group in _groups(blobs, expected, scale):
        stripes = _segment(image_bgr, probe, [blobs[k] for k in group], scale, expected)
        key = None if stripes is None else tuple(np.round(stripes.centroids.ravel(), 3))
        if stripes is not None and key not in seen:
            seen.add(key)
            yield stripes


def _coarse_blobs(crop: np.ndarray, probe: ProbeModel, scale: float, offset: tuple[int, int],
                  image_size: tuple[int, int]) -> list[_Blob]:
    """The largest stripe-coloured blobs of ``crop`` (at most ``_MAX_BLOBS``, largest first), in full-image pixels,
    without those touching the image border."""
    small = _reduced(crop, scale)
    n, _, stats, centroids = cv2.connectedComponentsWithStats(stripe_mask(small, probe), connectivity=8)
    width, height = image_size
    blobs = []
    for k in sorted(range(1, n), key=lambda k: -stats[k, cv2.CC_STAT_AREA]):
        if stats[k, cv2.CC_STAT_AREA] < _MIN_AREA_PX:
            break
        x, y, w, h = (int(v) for v in stats[k, :4])
        box = (int(x / scale) + offset[0], int(y / scale) + offset[1],
               int((x + w) / scale) + offset[0], int((y + h) / scale) + offset[1])
        if box[0] <= 0 or box[1] <= 0 or box[2] >= width or box[3] >= height:
            continue                                   # touches the image border: may be cut off
        blobs.append(_Blob(box, centroids[k] / scale + offset, float(stats[k, cv2.CC_STAT_AREA]), float(max(w, h))))
        if len(blobs) == _MAX_BLOBS:
            break
    return blobs


def _reduced(image: np.ndarray, scale: float) -> np.ndarray:
    """The image reduced by ``scale`` (each pixel the mean of the full pixels it covers): by halving (INTER_LINEAR at
    exactly half is the 2 x 2 mean) when the scale is a power of one half that divides the size, about three times
    cheaper than INTER_AREA's general path on a full-HD frame; INTER_AREA otherwise."""
    if scale == 1.0:
        return image
    factor = round(1.0 / scale)
    height, width = image.shape[:2]
    if factor & (factor - 1) == 0 and abs(factor * scale - 1.0) < 1e-9 and width % factor == 0 and height % factor == 0:
        while factor > 1:
            image = cv2.resize(image, (image.shape[1] // 2, image.shape[0] // 2), interpolation=cv2.INTER_LINEAR)
            factor //= 2
        return image
    return cv2.resize(image, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


def _groups(blobs: list[_Blob], expected: int, scale: float) -> Iterator[tuple[int, ...]]:
    """Indices of candidate groups: first, around the largest blob, the largest nearby ones (a clean view of the
    probe); then every other group of 2..``expected`` blobs near one another, the most stripe-like first."""
    if not blobs:
        return
    near = {}
    for lead, blob in enumerate(blobs):
        near[lead] = [k for k, other in enumerate(blobs)
                      if np.linalg.norm(other.centroid - blob.centroid) <= _NEAR_SIZES * blob.size / scale
                      and other.area >= 0.15 * blob.area]
    first = tuple(near[0][:expected])
    yield first
    others = set()
    for lead in range(len(blobs)):
        for size in range(min(expected, len(near[lead])), 1, -1):
            for group in itertools.combinations(near[lead], size):
                if lead in group and group != first:
                    others.add(tuple(sorted(group)))
    yield from sorted(others, key=lambda g: (-len(g), _irregularity(blobs, g)))


def _irregularity(blobs: list[_Blob], group: tuple[int, ...]) -> float:
    """How unlike a row of equal, evenly spaced bands a group is (0 = perfectly like it)."""
    centres = np.array([blobs[k].centroid for k in group])
    areas = np.array([blobs[k].area for k in group])
    centred = centres - centres.mean(axis=0)
    direction = np.linalg.svd(centred, full_matrices=False)[2][0]
    along = np.sort(centred @ direction)
    gaps = np.diff(along)
    off_line = np.abs(centred @ np.array([-direction[1], direction[0]])).max() / max(gaps.mean(), 1e-6)
    uneven = np.ptp(gaps) / max(gaps.mean(), 1e-6) if len(gaps) > 1 else 0.0
    return float(off_line + uneven + np.ptp(np.log(areas)))


def _segment(image_bgr: np.ndarray, probe: ProbeModel, group: list[_Blob], scale: float,
             expected: int) -> Stripes | None:
    """The group's stripes segmented at full resolution: inside the padded union of its boxes, the ``expected``
    largest components (at least 15% of the largest) whose centroid lies in one of its boxes, none touching the
    image border."""
    height, width = image_bgr.shape[:2]
    pad = int(2 / scale) + _EDGE_PAD_PX      # the coarse boxes miss a stripe's thin edges: none cut by the crop
    x0 = max(min(b.box[0] for b in group) - pad, 0)
    y0 = max(min(b.box[1] for b in group) - pad, 0)
    x1 = min(max(b.box[2] for b in group) + pad, width)
    y1 = min(max(b.box[3] for b in group) + pad, height)
    colour = _stripe_colour(image_bgr[y0:y1, x0:x1], probe)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(_open(colour), connectivity=8)
    boxes = np.array([b.box for b in group], float) + [-pad, -pad, pad, pad]

    def belongs(k: int) -> bool:
        cx, cy = centroids[k] + (x0, y0)
        left, top = stats[k, 0] + x0, stats[k, 1] + y0
        right, bottom = left + stats[k, 2], top + stats[k, 3]
        inside = np.any((boxes[:, 0] <= cx) & (cx <= boxes[:, 2]) & (boxes[:, 1] <= cy) & (cy <= boxes[:, 3]))
        return bool(inside) and left > 0 and top > 0 and right < width and bottom < height

    keep = [k for k in sorted(range(1, n), key=lambda k: -stats[k, cv2.CC_STAT_AREA]) if belongs(k)][:expected]
    if not keep:
        return None
    keep = [k for k in keep if stats[k, cv2.CC_STAT_AREA] >= 0.15 * stats[keep[0], cv2.CC_STAT_AREA]]
    labels, cents, areas = _rebuilt(labels, stats, centroids, keep, colour)
    cents = cents + np.array([x0, y0])
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
    return Stripes(cents[order], areas[order], direction, relabel[labels], (x0, y0, x1, y1))


def _rebuilt(labels: np.ndarray, stats: np.ndarray, centroids: np.ndarray, keep: list[int], colour: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kept stripes given back the stripe-coloured pixels the opening took from them (opening by
    reconstruction: each becomes the connected part of ``colour`` it lies in, unless that part holds another kept
    stripe or is much larger than it, i.e. runs into something else): (labels, centroids (k, 2), areas (k,)). The
    opening drops speckle but also a stripe's one-pixel edges, most where its flanks are dim (the image's corners)
    and differently in each eye: with a 4 mm baseline a tenth of a pixel of disparity is about half a millimetre at
    150 mm."""
    n, parts, part_stats, part_centroids = cv2.connectedComponentsWithStats(colour, connectivity=8)
    first_pixel = [np.flatnonzero(labels == k)[0] for k in keep]
    part_of = parts.ravel()[first_pixel]
    owners = np.bincount(part_of, minlength=n)
    lut = np.zeros(n, labels.dtype)
    rebuilt_centroids, areas = centroids[keep].copy(), stats[keep, cv2.CC_STAT_AREA].astype(float)
    for j, (k, part) in enumerate(zip(keep, part_of)):
        if owners[part] == 1 and part_stats[part, cv2.CC_STAT_AREA] <= _REBUILD_GROWTH * areas[j]:
            lut[part] = k
            rebuilt_centroids[j], areas[j] = part_centroids[part], part_stats[part, cv2.CC_STAT_AREA]
    rebuilt = lut[parts]
    kept_opened = np.isin(labels, keep) & (rebuilt == 0)
    rebuilt[kept_opened] = labels[kept_opened]
    return rebuilt, rebuilt_centroids, areas
