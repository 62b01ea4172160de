"""Coarse alignment of a keyframe with a view: the shift a noisy IMU leaves, and the insertion found by trying it.

Why: Lucas-Kanade needs a start within a few pixels, and both the IMU and a quick slide put the prediction tens of
pixels off: a rotation error of 0.5 degrees about the pivot moves the view by about three times as much as the
same turn of a camera that only turns (the pivot's lever moves the camera sideways), and a 5 mm slide zooms the
tissue by several percent. Both are found on the coarse band-passed images (:class:`~snreg.odometry.views.View`):
the keyframe is warped by the homography its tissue points would follow and correlated with the view over small
shifts (``cv2.matchTemplate``), which gives the shift that remains and how well the two agree. Along the one unknown,
the insertion, candidates are tried the same way (:func:`search_insertion`), and the best few start the exact
comparison; a view that agrees with no candidate (``MIN_RESPONSE``) gives none: a view never seen, or one that
changed, stays lost.
"""

from __future__ import annotations

import cv2
import numpy as np

from snreg.odometry.eyes import EyePair
from snreg.odometry.views import Keyframe, View

__all__ = ["MIN_RESPONSE", "coarse_shift", "search_insertion"]

MIN_RESPONSE = 0.3            # correlation of a view with a keyframe it shows
_REACH, _MIN_REACH_PX = 0.06, 4     # the largest shift looked for: a share of the coarse width, in coarse pixels
_SEARCH_REACH = 0.03                # while trying insertions: what the IMU's error leaves at the coarse scale


def coarse_shift(view: View, keyframe: Keyframe, homography: np.ndarray,
                 reach_share: float = _REACH) -> tuple[np.ndarray, float]:
    """The shift (2,) in working pixels that remains between ``view`` and ``keyframe`` warped by ``homography``
    (keyframe working pixels to predicted view pixels), at most ``reach_share`` of the image width (what the IMU's
    error can leave; a larger shift would follow something else, such as the probe), and how well the two agree
    there (normalised cross-correlation of the coarse band-passed images)."""
    height, width = view.coarse.shape
    reach = max(_MIN_REACH_PX, int(round(reach_share * width)))
    to_coarse = np.diag([1.0 / view.coarse_factor, 1.0 / view.coarse_factor, 1.0])
    coarse = to_coarse @ homography @ np.linalg.inv(to_coarse)
    warped = cv2.warpPerspective(keyframe.coarse, coarse, (width, height), flags=cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=128)
    scores = cv2.matchTemplate(warped, view.coarse[reach:height - reach, reach:width - reach], cv2.TM_CCOEFF_NORMED)
    _, best, _, (x, y) = cv2.minMaxLoc(scores)
    offset = np.array([x + _vertex(scores[y, x - 1:x + 2]), y + _vertex(scores[y - 1:y + 2, x])], float)
    return (reach - offset) * view.coarse_factor, float(best)


def search_insertion(pair: EyePair, view: View, keyframe: Keyframe, rotation_imu: np.ndarray, shaft: np.ndarray,
                     candidates_mm: np.ndarray, *, tries: int = 3) -> list[float]:
    """The insertions among ``candidates_mm`` (evenly spaced) at which ``keyframe`` agrees with ``view`` best: up to
    ``tries`` peaks of the agreement, best first, each refined between its neighbours; none reaching
    ``MIN_RESPONSE``: an empty list. The coarse images tell a few percent of scale apart only roughly, so each is a
    start for the exact comparison, not a measurement.

    ``rotation_imu``: current_from_keyframe (3, 3) from the IMU; ``shaft``: (3,) unit, camera frame."""
    candidates = np.asarray(candidates_mm, dtype=float)
    base = (keyframe.points + keyframe.insertion_mm * shaft) @ rotation_imu.T
    responses = np.full(len(candidates), -1.0)
    for k, insertion in enumerate(candidates):
        moved = base - insertion * shaft
        ahead = moved[:, 2] > 1.0
        homography = predicted_homography(keyframe.left_px[ahead], pair.project(moved[ahead], 0))
        if homography is not None:
            responses[k] = coarse_shift(view, keyframe, homography, _SEARCH_REACH)[1]
    padded = np.r_[-np.inf, responses, -np.inf]
    peaks = [k for k in range(len(candidates))
             if responses[k] >= MIN_RESPONSE and padded[k] < responses[k] >= padded[k + 2]]
    spacing = float(candidates[1] - candidates[0]) if len(candidates) > 1 else 0.0
    best = sorted(peaks, key=lambda k: -responses[k])[:tries]
    return [float(candidates[k]) + spacing * _vertex(responses[k - 1:k + 2]) if 0 < k < len(candidates) - 1
            else float(candidates[k]) for k in best]


def predicted_homography(points: np.ndarray, predicted: np.ndarray) -> np.ndarray | None:
    """The homography (3, 3) carrying working pixels ``points`` (N, 2) nearest to ``predicted`` (least squares), or
    None with fewer than 8 points or no fit."""
    if len(points) < 8:
        return None
    homography, _ = cv2.findHomography(np.asarray(points, np.float32), np.asarray(predicted, np.float32), 0)
    return homography if homography is not None and np.isfinite(homography).all() else None


def _vertex(three: np.ndarray) -> float:
    """Sub-pixel offset of a peak from three samples around it (0 at the border)."""
    if len(three) != 3:
        return 0.0
    curvature = float(three[0] - 2.0 * three[1] + three[2])
    return float(np.clip(0.5 * (three[0] - three[2]) / curvature, -0.5, 0.5)) if curvature < 0 else 0.0
