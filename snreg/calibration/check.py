"""Calibration QA: do these checkerboard views agree with this stereo calibration? (``snreg calibrate check``)

Why: a calibration's own reprojection RMS says how well it fits the views it was made from, not whether it
is right: one made from three copies of a single view fits them well and measures squares well, yet its
rectified rows are far apart. Endoscope optics also drift as they warm up, so in the operating room the
question "is this calibration still valid?" needs an answer from fresh views. Two figures answer it, each
independent of the calibration's own fit:

- epipolar error: after rectification (``R1 P1``, ``R2 P2``) matched corners of a pair lie on one image
  row; the RMS of their vertical disparity (px). A rotation of R by one degree, or intrinsics of another
  camera, shows at once (the tracker matches stripes along those rows).
- reconstruction error: corners triangulated with the rectified projections; the mean absolute
  difference between neighbouring-corner distances and the square size (mm), the figure the thesis
  reports. It mixes the calibration's error with triangulation noise, which with a 4 mm baseline is
  several per cent of a square at 20 cm, so the verdict uses its systematic part instead:
- scale error: the median signed relative difference between neighbouring-corner distances and the
  square (%). Noise averages out of it; a wrong baseline, focal length or a rotation of R about the
  vertical axis (which shifts every disparity) does not.

Verdict: "bad" when the epipolar or the scale error is over its BAD threshold, "check" when over its GOOD
threshold, else "good"; ``reasons`` say which figure decided it, with the threshold. The thresholds are
stated below and in every report. Figures measured (tests/test_calibration_check.py): OpenCV's stereo
samples through their own calibration 0.13 px and 0.02 %; with R turned by 1 degree about x 9.1 px,
about y a scale error of -6.9 %, about z 1.7 px.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from snreg.calibration.checkerboard import Board, find_corners
from snreg.calibration.coverage import SIMILAR_SHIFT_FRACTION, mean_corner_shift
from snreg.camera import StereoCalibration

__all__ = ["CalibrationCheck", "check_views", "check_images", "rectified_corners", "corner_steps",
           "near_identical_views", "EPIPOLAR_GOOD_PX", "EPIPOLAR_BAD_PX", "SCALE_GOOD", "SCALE_BAD", "PROVISIONAL_VIEWS"]

EPIPOLAR_GOOD_PX, EPIPOLAR_BAD_PX = 1.0, 1.5     # RMS vertical disparity of rectified matched corners; the
                                                  # stereo search follows image rows, and tolerates about 1 px
SCALE_GOOD, SCALE_BAD = 0.015, 0.025             # |median (neighbour distance - square) / square|; triangulation
                                                  # noise alone biases it by up to ~0.7 % (4 mm baseline, 20-35 cm)
PROVISIONAL_VIEWS = 8            # a calibration from fewer distinct views than this is provisional
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)


@dataclass(frozen=True)
class CalibrationCheck:
    """The check of one calibration on ``views`` board views (mm, px).

    ``view_epipolar_px`` (n,): RMS vertical disparity per view; ``view_reconstruction_mm`` (n,): mean
    |neighbouring-corner distance - square| per view; ``scale_error``: median signed (distance - square) /
    square over all views; ``skipped``: images in which the board was not found (left out).
    """

    epipolar_rms_px: float
    reconstruction_mm: float
    scale_error: float
    views: int
    view_epipolar_px: np.ndarray
    view_reconstruction_mm: np.ndarray
    verdict: str
    reasons: tuple[str, ...]
    skipped: tuple[str, ...] = field(default=())

    def as_json(self) -> dict:
        """``{"epipolar_rms_px", "reconstruction_mm", "views", "verdict", "reasons", ...}`` (docs/design.md, Contracts)."""
        return {"epipolar_rms_px": round(self.epipolar_rms_px, 4), "reconstruction_mm": round(self.reconstruction_mm, 4),
                "views": self.views, "verdict": self.verdict, "reasons": list(self.reasons),
                "scale_percent": round(100 * self.scale_error, 3),
                "thresholds": {"epipolar_rms_px": {"good": EPIPOLAR_GOOD_PX, "bad": EPIPOLAR_BAD_PX},
                               "scale_percent": {"good": 100 * SCALE_GOOD, "bad": 100 * SCALE_BAD}},
                "view_epipolar_px": [round(float(v), 4) for v in self.view_epipolar_px],
                "view_reconstruction_mm": [round(float(v), 4) for v in self.view_reconstruction_mm],
                "skipped": list(self.skipped)}

    def summary(self) -> str:
        """One line: both figures and the verdict."""
        return (f"epipolar error {self.epipolar_rms_px:.3f} px RMS, reconstruction error {self.reconstruction_mm:.3f} mm, "
                f"scale error {100 * self.scale_error:+.2f}% over {self.views} view(s): {self.verdict}")


def rectified_corners(calib: StereoCalibration, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corners (N, 2) px of one pair mapped into the rectified images (undistorted, ``R1 P1`` and ``R2 P2``)."""
    rect_l = cv2.undistortPoints(np.asarray(left, np.float64).reshape(-1, 1, 2), calib.K1, calib.D1, R=calib.R1,
                                 P=calib.P1, criteria=_UNDISTORT_CRITERIA).reshape(-1, 2)
    rect_r = cv2.undistortPoints(np.asarray(right, np.float64).reshape(-1, 1, 2), calib.K2, calib.D2, R=calib.R2,
                                 P=calib.P2, criteria=_UNDISTORT_CRITERIA).reshape(-1, 2)
    return rect_l, rect_r


def corner_steps(calib: StereoCalibration, left: Sequence[np.ndarray], right: Sequence[np.ndarray],
                 board: Board) -> list[np.ndarray]:
    """Per view, the distances (mm) between neighbouring corners triangulated in the rectified frame."""
    steps = []
    for corners_l, corners_r in zip(left, right):
        rect_l, rect_r = rectified_corners(calib, corners_l, corners_r)
        homogeneous = cv2.triangulatePoints(calib.P1, calib.P2, rect_l.T, rect_r.T)
        grid = (homogeneous[:3] / homogeneous[3]).T.reshape(board.rows, board.cols, 3)
        steps.append(np.concatenate([np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel(),
                                     np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel()]))
    return steps


def check_views(calib: StereoCalibration, left: Sequence[np.ndarray], right: Sequence[np.ndarray], board: Board, *,
                skipped: Sequence[str] = ()) -> CalibrationCheck:
    """Check ``calib`` on matched corner detections of ``board``: (n, cols * rows, 2) px per eye, n >= 1."""
    if len(left) == 0 or len(left) != len(right):
        raise ValueError(f"a calibration check needs matched board views in both eyes, got {len(left)} left and "
                         f"{len(right)} right")
    vertical = [np.diff([a[:, 1] for a in rectified_corners(calib, l_, r_)], axis=0).ravel() for l_, r_ in zip(left, right)]
    view_epipolar = np.array([np.sqrt(np.mean(v ** 2)) for v in vertical])
    epipolar = float(np.sqrt(np.mean(np.concatenate(vertical) ** 2)))
    steps = corner_steps(calib, left, right, board)
    view_mm = np.array([np.abs(s - board.square_mm).mean() for s in steps])
    reconstruction = float(view_mm.mean())
    scale = float(np.median(np.concatenate(steps)) / board.square_mm - 1.0)
    verdict, reasons = _verdict(epipolar, reconstruction, scale)
    if not np.isfinite(epipolar) or not np.isfinite(reconstruction) or not np.isfinite(scale):
        verdict, reasons = "bad", ("the calibration maps these corners to no finite position: it does not belong "
                                   "to these cameras",)
    return CalibrationCheck(epipolar, reconstruction, scale, len(left), view_epipolar, view_mm, verdict, reasons,
                            tuple(skipped))


def check_images(calib: StereoCalibration, left_images: Sequence[np.ndarray], right_images: Sequence[np.ndarray],
                 board: Board, names: Sequence[str] | None = None, progress=None) -> CalibrationCheck:
    """Find ``board`` in each image pair (grey or BGR, the calibration's size) and check ``calib`` on the pairs
    where both eyes show it; ``ValueError`` when sizes differ or no pair shows the board. ``progress(done, total)``
    is called after each pair."""
    names = list(names) if names is not None else [f"pair {i + 1}" for i in range(len(left_images))]
    left, right, skipped = [], [], []
    for k, (image_l, image_r) in enumerate(zip(left_images, right_images)):
        for image in (image_l, image_r):
            size = (image.shape[1], image.shape[0])
            if size != tuple(calib.image_size):
                raise ValueError(f"{names[k]} is {size[0]}x{size[1]} but the calibration is for "
                                 f"{calib.image_size[0]}x{calib.image_size[1]} images; use views from the same cameras and mode")
        corners_l = find_corners(image_l, board)
        corners_r = find_corners(image_r, board) if corners_l is not None else None
        if corners_l is None or corners_r is None:
            skipped.append(f"{names[k]} ({'left' if corners_l is None else 'right'})")
        else:
            left.append(corners_l)
            right.append(corners_r)
        if progress:
            progress(k + 1, len(left_images))
    if not left:
        raise ValueError(f"board {board.cols}x{board.rows} (inner corners) found in no pair ({len(left_images)} given); "
                         "check --board (inner corners, e.g. 10x7 for 11 x 8 squares) and that the board is in view")
    return check_views(calib, left, right, board, skipped=skipped)


def near_identical_views(left: Sequence[np.ndarray], right: Sequence[np.ndarray], image_size: tuple[int, int], *,
                         fraction: float = SIMILAR_SHIFT_FRACTION) -> tuple[int, list[tuple[int, int]]]:
    """How many distinct views there are, and the (later, earlier) index pairs of views that repeat an earlier one.

    Two views are the same when both eyes' corners moved less than ``fraction`` of the image diagonal on
    average (:data:`~snreg.calibration.coverage.SIMILAR_SHIFT_FRACTION`, the wizard's "too similar").
    """
    tolerance = fraction * float(np.hypot(*image_size))
    distinct, repeats = [], []
    for k, (corners_l, corners_r) in enumerate(zip(left, right)):
        same = [i for i in distinct if max(mean_corner_shift(corners_l, left[i]), mean_corner_shift(corners_r, right[i]))
                < tolerance]
        if same:
            repeats.append((k, same[0]))
        else:
            distinct.append(k)
    return len(distinct), repeats


def _verdict(epipolar_px: float, reconstruction_mm: float, scale: float) -> tuple[str, tuple[str, ...]]:
    """("good" | "check" | "bad", reasons) from the thresholds at the top of the module."""
    epipolar = (f"epipolar error {epipolar_px:.3f} px RMS (good <= {EPIPOLAR_GOOD_PX:g}, bad > {EPIPOLAR_BAD_PX:g} px)")
    recon = (f"scale error {100 * scale:+.2f}% (median distance of neighbouring corners against the square; good "
             f"<= {100 * SCALE_GOOD:g}%, bad > {100 * SCALE_BAD:g}%; mean reconstruction error {reconstruction_mm:.3f} mm)")
    bad, check = [], []
    if epipolar_px > EPIPOLAR_BAD_PX:
        bad.append(f"{epipolar}: matched corners lie on different rows after rectification, so R, T or the intrinsics "
                   "do not fit these cameras")
    elif epipolar_px > EPIPOLAR_GOOD_PX:
        check.append(f"{epipolar}: rectified rows disagree a little; recalibrate if it grows")
    if abs(scale) > SCALE_BAD:
        bad.append(f"{recon}: distances come out at the wrong scale (baseline, focal length or R)")
    elif abs(scale) > SCALE_GOOD:
        check.append(f"{recon}: distances are a little off")
    if bad:
        return "bad", tuple(bad + check)
    if check:
        return "check", tuple(check)
    return "good", (epipolar, recon)
