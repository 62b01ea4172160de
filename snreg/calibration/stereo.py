"""Mono and stereo checkerboard calibration (thesis §4.2), with per-view errors and a 3D check.

Stereo calibration first calibrates each eye (``cv2.calibrateCamera``), then refines both eyes and
the pair jointly (``cv2.stereoCalibrate`` with ``CALIB_USE_INTRINSIC_GUESS``). Measured on rendered
boards (thesis cameras at half size, 15 views, 4 seeds): keeping the mono intrinsics fixed (OpenCV's
default) left baseline errors of 0.2-1.0 % of the 4.3 mm baseline, the joint refinement 0.02-0.11 %.

The reconstruction error triangulates every view's corners with the rectified projections ``P1, P2``
and compares neighbouring-corner distances with the square size: a check in mm, independent of the
reprojection RMS, of what the tracking will measure. With the epipolar error it is the calibration
check of :mod:`snreg.calibration.check`, run here on the calibration's own views, which also flags
near-identical views and a calibration from too few distinct views.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from snreg.calibration.check import PROVISIONAL_VIEWS, CalibrationCheck, check_views, near_identical_views
from snreg.calibration.checkerboard import Board, find_corners
from snreg.calibration.coverage import SIMILAR_SHIFT_FRACTION
from snreg.calibration.images import expand_globs, read_grey
from snreg.camera import StereoCalibration

__all__ = ["MIN_VIEWS", "SUSPECT_FACTOR", "MonoCalibration", "StereoResult", "ImagePairs", "calibrate_mono", "calibrate_stereo",
           "calibrate_stereo_corners", "drop_views", "load_image_pairs"]

MIN_VIEWS = 3
SUSPECT_FACTOR = 2.0      # a view whose worse eye's error is above this many times the median error is suspect
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)


@dataclass(frozen=True)
class MonoCalibration:
    """One camera: ``K`` (3, 3), ``D`` (1, 5), RMS and per-view RMS reprojection errors (n,) in px."""

    image_size: tuple[int, int]
    K: np.ndarray
    D: np.ndarray
    rms_px: float
    view_errors_px: np.ndarray


@dataclass(frozen=True)
class StereoResult:
    """A stereo calibration with what is needed to judge it and to rerun it without some views.

    ``view_ids`` (n,) are the kept views' indices in the input pair lists; ``view_errors_px`` (n, 2)
    their RMS reprojection errors, left and right; ``eye_rms_px`` (2,) the per-eye RMS of the stereo
    fit and ``mono_rms_px`` (2,) that of each eye calibrated alone; ``view_reconstruction_mm`` (n,)
    and ``reconstruction_error_mm`` the mean absolute error of triangulated neighbouring-corner
    distances against the square size. ``left_corners``/``right_corners`` (n, cols * rows, 2) are the
    detections; ``skipped`` names, per skipped pair, an image in which the board was not found.
    ``check``: :func:`~snreg.calibration.check.check_views` of the calibration on its own views (its epipolar
    error shows a calibration that fits its views but not the cameras); ``distinct_views`` and
    ``repeated_views`` ((view id, id of the earlier view it repeats), ...) from
    :func:`~snreg.calibration.check.near_identical_views`.
    """

    calibration: StereoCalibration
    board: Board
    view_ids: np.ndarray
    view_errors_px: np.ndarray
    eye_rms_px: np.ndarray
    mono_rms_px: np.ndarray
    view_reconstruction_mm: np.ndarray
    reconstruction_error_mm: float
    left_corners: np.ndarray
    right_corners: np.ndarray
    skipped: tuple[str, ...] = ()
    check: CalibrationCheck | None = None
    distinct_views: int = 0
    repeated_views: tuple[tuple[int, int], ...] = ()

    @property
    def rms_px(self) -> float:
        """Stereo RMS reprojection error over both eyes, px."""
        return self.calibration.rms_reprojection_px

    @property
    def n_views(self) -> int:
        return len(self.view_ids)

    def warnings(self) -> list[str]:
        """Sentences about what makes this calibration doubtful: repeated views, too few distinct views, its check."""
        notes = []
        if self.repeated_views:
            pairs = ", ".join(f"{a} repeats {b}" for a, b in self.repeated_views[:6])
            more = f" and {len(self.repeated_views) - 6} more" if len(self.repeated_views) > 6 else ""
            notes.append(f"near-identical views (corners within {100 * SIMILAR_SHIFT_FRACTION:g}% of the image diagonal): "
                         f"view {pairs}{more}; a repeated view adds nothing, so move or tilt the board between views")
        if self.distinct_views < PROVISIONAL_VIEWS:
            notes.append(f"only {self.distinct_views} distinct view(s): this calibration is provisional; capture at least "
                         f"{PROVISIONAL_VIEWS} distinct views (the thesis took 30) all over the image")
        if self.check is not None and self.check.verdict != "good":
            notes.append(f"check on its own views: {self.check.verdict}: {'; '.join(self.check.reasons)}")
        return notes

    @property
    def suspect_views(self) -> np.ndarray:
        """(n,) bool: views worth checking (and perhaps dropping), by ``SUSPECT_FACTOR`` x the median error."""
        return self.view_errors_px.max(axis=1) > SUSPECT_FACTOR * np.median(self.view_errors_px)


@dataclass(frozen=True)
class ImagePairs:
    """Grey uint8 images (H, W) paired by naturally sorted file name, with their paths."""

    left: list[np.ndarray]
    right: list[np.ndarray]
    left_paths: list[str]
    right_paths: list[str]


def calibrate_mono(images: Sequence[np.ndarray], board: Board) -> MonoCalibration:
    """Calibrate one camera from images of ``board`` (``cv2.calibrateCamera``, 5 distortion terms)."""
    names = [f"image {i}" for i in range(len(images))]
    _check_sizes(images, names)
    corners = [find_corners(image, board) for image in images]
    found = [c for c in corners if c is not None]
    if len(found) < MIN_VIEWS:
        missing = _first([name for name, c in zip(names, corners) if c is None])
        raise ValueError(f"board {board.cols}x{board.rows} (inner corners) found in only {len(found)} of {len(images)} "
                         f"images, need {MIN_VIEWS}; not found in {missing}")
    return _mono(found, board, _size(images[0]))


def calibrate_stereo(left_images: Sequence[np.ndarray], right_images: Sequence[np.ndarray], board: Board, *,
                     left_names: Sequence[str] | None = None, right_names: Sequence[str] | None = None) -> StereoResult:
    """Calibrate a stereo pair from synchronous image pairs of ``board``; pairs match by index.

    Pairs in which either image lacks the board are skipped (``skipped`` names the first image without
    it; the right one is not searched when the left lacks it, as a failed search is slow); fewer than
    :data:`MIN_VIEWS` usable pairs raise ``ValueError`` naming the images. The names only label messages.
    """
    left_names = list(left_names) if left_names is not None else [f"left image {i}" for i in range(len(left_images))]
    right_names = list(right_names) if right_names is not None else [f"right image {i}" for i in range(len(right_images))]
    _check_pairs(left_images, right_images, left_names, right_names)
    ids, left, right, skipped = [], [], [], []
    for i, (image_l, image_r) in enumerate(zip(left_images, right_images)):
        corners_l = find_corners(image_l, board)
        corners_r = find_corners(image_r, board) if corners_l is not None else None
        if corners_l is None or corners_r is None:
            skipped.append(left_names[i] if corners_l is None else right_names[i])
        else:
            ids.append(i)
            left.append(corners_l)
            right.append(corners_r)
    if len(ids) < MIN_VIEWS:
        found = f"board {board.cols}x{board.rows} (inner corners) found in both images of only {len(ids)} of {len(left_images)} pairs"
        if not skipped:
            raise ValueError(f"{found}, but a stereo calibration needs at least {MIN_VIEWS} pairs (and {PROVISIONAL_VIEWS} "
                             "or more distinct views not to be provisional); give more pairs")
        hint = ("check the board size (inner corners, e.g. 10x7 for 11 x 8 squares) and that the board is in view"
                if not ids else "give more pairs showing the whole board in both images")
        raise ValueError(f"{found}, need {MIN_VIEWS}; not found in {_first(skipped)}; {hint}")
    return _solve(np.array(ids), np.array(left), np.array(right), board, _size(left_images[0]), tuple(skipped))


def calibrate_stereo_corners(left_corners: np.ndarray, right_corners: np.ndarray, board: Board,
                             image_size: tuple[int, int]) -> StereoResult:
    """Calibrate from corners already detected: (n, cols * rows, 2) float32 per eye, in ``board.object_points()``
    order, in images of ``image_size`` (width, height); what :func:`calibrate_stereo` does after detection (the
    error budget feeds it simulated detections)."""
    left, right = (np.asarray(c, dtype=np.float32).reshape(-1, board.n_corners, 2) for c in (left_corners, right_corners))
    if len(left) != len(right) or len(left) < MIN_VIEWS:
        raise ValueError(f"need the same number of views per eye, at least {MIN_VIEWS}; got {len(left)} and {len(right)}")
    return _solve(np.arange(len(left)), left, right, board, tuple(image_size), ())


def drop_views(result: StereoResult, view_ids: Sequence[int]) -> StereoResult:
    """Recalibrate without the views whose ids (indices in the original pair lists) are given."""
    unknown = sorted(set(int(v) for v in view_ids) - set(result.view_ids.tolist()))
    if unknown:
        raise ValueError(f"cannot drop view(s) {', '.join(map(str, unknown))}: the calibration has views "
                         f"{', '.join(map(str, result.view_ids))}")
    keep = ~np.isin(result.view_ids, list(view_ids))
    if keep.sum() < MIN_VIEWS:
        raise ValueError(f"dropping {len(result.view_ids) - keep.sum()} views leaves {keep.sum()}, need at least {MIN_VIEWS}")
    return _solve(result.view_ids[keep], result.left_corners[keep], result.right_corners[keep], result.board,
                  result.calibration.image_size, result.skipped)


def load_image_pairs(left_patterns: str | Sequence[str], right_patterns: str | Sequence[str]) -> ImagePairs:
    """Read the images matching two glob patterns (or lists of them) as grey, paired by natural sort order.

    Natural order puts ``left2`` before ``left10``. Raises ``ValueError`` for no matching files,
    unequal counts, unreadable files or images of different sizes.
    """
    left_paths, right_paths = expand_globs(left_patterns, "left"), expand_globs(right_patterns, "right")
    if len(left_paths) != len(right_paths):
        n = min(len(left_paths), len(right_paths))
        extra = (left_paths if len(left_paths) > n else right_paths)[n]
        raise ValueError(f"{len(left_paths)} left but {len(right_paths)} right images; they are paired by sorted "
                         f"name, so the counts must match (first unpaired: {extra})")
    left, right = [read_grey(p) for p in left_paths], [read_grey(p) for p in right_paths]
    _check_pairs(left, right, left_paths, right_paths)
    return ImagePairs(left, right, left_paths, right_paths)


def _solve(ids: np.ndarray, left: np.ndarray, right: np.ndarray, board: Board, size: tuple[int, int],
           skipped: tuple[str, ...]) -> StereoResult:
    """Mono-calibrate both eyes, refine jointly, rectify, and measure (left, right: (n, N, 2) float32)."""
    objects = [board.object_points()] * len(ids)
    mono_l, mono_r = _mono(list(left), board, size), _mono(list(right), board, size)
    rms, K1, D1, K2, D2, R, T, _, _, _, _, per_view = cv2.stereoCalibrateExtended(
        objects, list(left), list(right), mono_l.K, mono_l.D, mono_r.K, mono_r.D, size, None, None,
        flags=cv2.CALIB_USE_INTRINSIC_GUESS)
    calibration = StereoCalibration.from_pair(size, K1, D1, K2, D2, R, T, rms_reprojection_px=float(rms),
                                              board_cols=board.cols, board_rows=board.rows,
                                              square_mm=float(board.square_mm), n_views=len(ids))
    per_view = np.asarray(per_view, dtype=float).reshape(-1, 2)
    check = check_views(calibration, left, right, board)
    distinct, repeats = near_identical_views(left, right, size)
    return StereoResult(calibration, board, ids, per_view, np.sqrt(np.mean(per_view ** 2, axis=0)),
                        np.array([mono_l.rms_px, mono_r.rms_px]), check.view_reconstruction_mm, check.reconstruction_mm,
                        left, right, skipped, check, distinct, tuple((int(ids[a]), int(ids[b])) for a, b in repeats))


def _mono(corners: list[np.ndarray], board: Board, size: tuple[int, int]) -> MonoCalibration:
    rms, K, D, _, _, _, _, per_view = cv2.calibrateCameraExtended(
        [board.object_points()] * len(corners), corners, size, None, None)
    return MonoCalibration(size, K, D.reshape(1, -1), float(rms), np.asarray(per_view, dtype=float).ravel())


def _first(names: Sequence[str], n: int = 6) -> str:
    """The first ``n`` names, comma-separated, and how many more."""
    more = f" and {len(names) - n} more" if len(names) > n else ""
    return ", ".join(names[:n]) + more


def _size(image: np.ndarray) -> tuple[int, int]:
    return (int(image.shape[1]), int(image.shape[0]))


def _check_sizes(images: Sequence[np.ndarray], names: Sequence[str]) -> None:
    if len(images) == 0:
        raise ValueError("no images given")
    first = _size(images[0])
    for image, name in zip(images, names):
        if _size(image) != first:
            raise ValueError(f"images differ in size: {names[0]} is {first[0]}x{first[1]} but {name} is "
                             f"{_size(image)[0]}x{_size(image)[1]}; all images of a calibration must have one size")


def _check_pairs(left: Sequence[np.ndarray], right: Sequence[np.ndarray], left_names: Sequence[str],
                 right_names: Sequence[str]) -> None:
    if len(left) != len(right):
        raise ValueError(f"{len(left)} left but {len(right)} right images; each left image needs its right partner")
    _check_sizes(list(left) + list(right), list(left_names) + list(right_names))
