"""A stereo calibration at the insertion tracker's working scale: grey images, working pixels <-> the full image's,
normalised coordinates, projection and triangulation.

Why: tracking the insertion must cost a few milliseconds per full-HD pair (issue 27: at most 10 ms), so it works
on grey images reduced to about 640 pixels wide: by the largest whole factor keeping them that wide (a full-HD pair by
3: at a third the insertion's error on three seeded full-HD surgery videos of ``snreg bench`` was about that at half,
mean 0.010-0.026 mm against 0.024-0.031, and each image operation costs less than half), or, a pair 1.5 to 2 times that
wide, by a factor of its own (the demo's 960x540 by 1.5 to 640x360, issue 36: an area mean; left at full size it cost
the insertion more than a full-HD pair, and ``snreg experiment camera --seeds 11,12,13 --scale 0.5`` erred less:
docs/method/insertion.md), while every coordinate it hands to the motion fit is exact: working pixels map back to the
centre of the full pixels they were made of, then through the calibration's own distortion to normalised
coordinates.
"""

from __future__ import annotations

import cv2
import numpy as np

from snreg.camera import StereoCalibration
from snreg.geometry import make_transform

__all__ = ["EyePair"]


class EyePair:
    """A stereo calibration at the working scale: grey images, pixels <-> normalised coordinates, projection and
    triangulation, all in the left camera frame (mm). ``factor``: full pixels per working pixel (whole, or from 1.5
    to 2), ``size``: the working images' (width, height)."""

    def __init__(self, calibration: StereoCalibration, work_width: int):
        self.calibration = calibration
        width, height = calibration.image_size
        whole = max(1, width // work_width)
        if whole == 1 and width >= 1.5 * work_width:
            # 1.5 to 2 times the working width (the demo's 960x540): reduced to it by a factor of its own, not left at
            # full size, where it cost the insertion more than a full-HD pair (issue 36)
            self.factor = width / work_width
            self.size = (work_width, round(height / self.factor))
            self._scale = np.array([self.factor, height / self.size[1]])   # full pixels per working pixel, x and y
        else:
            self.factor, self.size = whole, (width // whole, height // whole)
            self._scale = np.full(2, float(whole))
        self.focal_px = float(calibration.K1[0, 0]) / self.factor
        self.right_from_left = make_transform(calibration.R, calibration.T.ravel())
        self._eyes = ((calibration.K1, calibration.D1, np.zeros(3), np.zeros(3)),
                      (calibration.K2, calibration.D2, cv2.Rodrigues(calibration.R)[0].ravel(), calibration.T.ravel()))
        self._rectify = ((calibration.R1, calibration.P1), (calibration.R2, calibration.P2))

    def grey(self, image: np.ndarray, eye: str) -> np.ndarray:
        """The BGR frame as a grey uint8 image at the working scale; ValueError for a frame of another size."""
        width, height = self.calibration.image_size
        if image is None or image.ndim != 3 or image.shape[2] != 3:
            raise ValueError(f"the {eye} image must be a colour (BGR) image")
        if image.shape[1] != width or image.shape[0] != height:
            raise ValueError(f"the {eye} image is {image.shape[1]}x{image.shape[0]} but the calibration is for "
                             f"{width}x{height}; use the matching calibration file")
        if self.factor == 1:
            return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if self.factor != int(self.factor):          # the area mean, centred on full pixel (px + 0.5) factor - 0.5
            return cv2.resize(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), self.size, interpolation=cv2.INTER_AREA)
        crop = image[:self.size[1] * self.factor, :self.size[0] * self.factor]
        if self.factor == 2 or (self.factor == 3 and self.size[0] % 2 == 0 and self.size[1] % 2 == 0):
            # halved first (INTER_LINEAR at exactly half is the 2 x 2 mean) and made grey on the quarter of the pixels:
            # a full-HD frame's colour conversion and reduction cost half as much; a third is that half reduced by 1.5
            # (INTER_LINEAR: a 4-pixel kernel centred, as the 3 x 3 mean, on full pixel 3x + 1, and as quiet)
            half = cv2.cvtColor(cv2.resize(crop, (crop.shape[1] // 2, crop.shape[0] // 2),
                                           interpolation=cv2.INTER_LINEAR), cv2.COLOR_BGR2GRAY)
            return half if self.factor == 2 else cv2.resize(half, self.size, interpolation=cv2.INTER_LINEAR)
        return cv2.resize(cv2.cvtColor(crop, cv2.COLOR_BGR2GRAY), self.size, interpolation=cv2.INTER_AREA)

    def normalise(self, px: np.ndarray, eye: int) -> np.ndarray:
        """(N, 2) working pixels of eye 0 (left) or 1 (right) -> normalised coordinates in that camera's frame."""
        K, D = self._eyes[eye][:2]
        return cv2.undistortPoints(self.full(px).reshape(-1, 1, 2), K, D).reshape(-1, 2)

    def project(self, points: np.ndarray, eye: int) -> np.ndarray:
        """(N, 2) working pixels in eye 0 or 1 of left-camera points (N, 3) mm."""
        K, D, rvec, tvec = self._eyes[eye]
        full = cv2.projectPoints(np.asarray(points, np.float64).reshape(-1, 1, 3), rvec, tvec, K, D)[0].reshape(-1, 2)
        return (full - (self._scale - 1) / 2.0) / self._scale

    def full(self, px: np.ndarray) -> np.ndarray:
        """(N, 2) full-image pixels of working pixels: the centre of the full pixels each was made of."""
        return np.asarray(px, dtype=np.float64) * self._scale + (self._scale - 1) / 2.0

    def epipolar_gap_px(self, left_px: np.ndarray, right_px: np.ndarray) -> np.ndarray:
        """(N,) vertical offset between matched points after rectification, working pixels (0 for a true match)."""
        gaps = []
        for eye, px in enumerate((left_px, right_px)):
            K, D = self._eyes[eye][:2]
            R, P = self._rectify[eye]
            gaps.append(cv2.undistortPoints(self.full(px).reshape(-1, 1, 2), K, D, R=R, P=P).reshape(-1, 2)[:, 1])
        return np.abs(gaps[0] - gaps[1]) / self._scale[1]

    def triangulate(self, left_norm: np.ndarray, right_norm: np.ndarray) -> np.ndarray:
        """(N, 3) mm left-camera points from normalised coordinates in both eyes."""
        homog = cv2.triangulatePoints(np.eye(3, 4), self.right_from_left[:3], left_norm.T.astype(np.float64),
                                      right_norm.T.astype(np.float64))
        return (homog[:3] / homog[3]).T
