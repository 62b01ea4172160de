"""Stereo pairs at the working scale (:class:`~snreg.odometry.eyes.EyePair`), and keyframes: tissue points
triangulated from one pair, to follow in later ones.

A :class:`View` is a pair's grey images at the working scale, band-passed (the light moves with the camera), with
where tissue may be followed. A :class:`Keyframe` is a pair whose tissue features (corners away from the probe and
the border) were matched left to right (pyramidal Lucas-Kanade, checked backwards and against the epipolar line)
and triangulated; later pairs are compared with it, not with their predecessor, so noise does not accumulate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np
from scipy.spatial import cKDTree

from snreg.odometry.eyes import EyePair
from snreg.probe import ProbeModel

__all__ = ["OdometryParams", "PairImages", "View", "Keyframe", "make_keyframe", "keyframe_corners", "follow",
           "across", "lucas_kanade", "inside"]


@dataclass(frozen=True)
class OdometryParams:
    """Tuning of the insertion tracker; pixels at the working scale, mm, degrees."""

    work_width: int = 640                 # the pair is reduced to about this wide (:class:`~snreg.odometry.eyes.EyePair`)
    max_features: int = 220               # tissue corners per keyframe
    max_followed: int = 130               # of them followed into a pair at most (the strongest in view)
    min_distance_px: int = 16             # between them
    border_px: int = 14                   # none this close to the image border
    lk_window_px: int = 17
    lk_levels: int = 2
    min_points: int = 30                  # fewer agreeing points: lost
    min_agreeing_share: float = 0.5       # of the points followed
    max_sd_mm: float = 1.5                # the insertion's standard error above this: lost
    rotation_sd_deg: float = 0.5          # the IMU's relative rotation, per axis
    noise_px: float = 0.3                 # the features' position noise
    fresh_scale: float = 0.06             # a keyframe is fresh within this log-scale change of the view ...
    fresh_angle_deg: float = 4.0          # ... and this turn; a new one is made when none is
    usable_scale: float = 0.2             # a keyframe is followed up to this log-scale change ...
    usable_angle_deg: float = 9.0         # ... and this turn
    min_texture: float = 1.0              # band-pass deviation (grey levels) of a view with tissue in it (noise: 0.3-0.6)
    max_blur_ratio: float = 1.6           # a view of this many times less contrast than its keyframe is blurred
    max_keyframes: int = 48
    search_scale: float = 0.3             # a lost view is searched for this far in log-scale from each keyframe


_FINE_PX, _COARSE_PX, _GAIN = 0.8, 8.0, 3.0      # band-pass of the working images (px at the working scale)
# the fine blur's kernel: 5 taps, not the 7 OpenCV picks for sigma 0.8 (issue 36): on uint8 its fixed-point weights
# of the outer two are 0, so the image is the same to the bit (tests/test_odometry.py) at half the blur's cost
_FINE_TAPS = 5
# the wide blur (sigma 2 on the image a quarter the size) by OpenCV's own 13-tap kernel for it, applied by sepFilter2D:
# GaussianBlur's bit-exact uint8 path cost four times as much on so small an image (issue 36); 1 pixel in 140 differs
# by one grey level (a smooth change of the light, which the band-pass removes anyway)
_WIDE_KERNEL = cv2.getGaussianKernel(13, _COARSE_PX / 4.0)
_MID = 128
_UNWARPED = 0.01                                     # a homography this close to a shift is not warped for
_NEAR_MM, _PROBE_SAMPLES = 5.0, 8                   # the probe's outline in the masks
_EDGE_CAP = 24                                       # band-pass deviations counted towards the texture, at most
COARSE_MAX_WIDTH = 400                              # the coarse images: pyramid levels down to at most this wide
# Lucas-Kanade stops after this many steps or at a step this small (px): 10 and 0.03, not 20 and 0.01 (issue 36: about
# a tenth of its time; with at most 130 points a pair, snreg experiment camera --seeds 7,8,9,10 stayed within 0.015 mm
# median and 0.041 mm at most, docs/method/insertion.md)
_LK_STEPS, _LK_EPS_PX = 10, 0.03
ACROSS_LEVELS = 0                                    # pyramid levels of the match across a pair (:func:`across`)
_MIN_MATCHED = 8                                     # matched points a keyframe's corners are matched across from


@dataclass(frozen=True, eq=False)
class PairImages:
    """What a pair's view needs that the probe's fix does not change, so it can be made beside the probe tracker (a
    thread of its own: OpenCV releases the GIL): both eyes band-passed at the working scale (:func:`band_pass`), the
    left one's deviation from mid-grey (every other pixel, capped: the probe's edges count once) and its plain
    brightness, and the plain left grey image, from which :attr:`coarse` is made when first asked for."""

    left: np.ndarray
    right: np.ndarray
    deviation: np.ndarray
    brightness: float
    plain_left: np.ndarray

    @classmethod
    def of(cls, pair: EyePair, left: np.ndarray, right: np.ndarray) -> "PairImages":
        """The images of a BGR pair; ValueError for frames of another size than the calibration's."""
        plain_left = pair.grey(left, "left")
        grey_left, grey_right = band_pass(plain_left), band_pass(pair.grey(right, "right"))
        deviation = np.minimum(cv2.absdiff(grey_left[::2, ::2], _MID), _EDGE_CAP)
        return cls(grey_left, grey_right, deviation, cv2.mean(plain_left)[0], plain_left)

    @cached_property
    def coarse(self) -> tuple[np.ndarray, int]:
        """The left image band-passed ``factor`` times smaller (at most ``COARSE_MAX_WIDTH`` wide), and ``factor``.
        Made when first asked for (issue 36): only a view that is searched for (:mod:`snreg.odometry.search`) or a
        keyframe that is searched in needs it, a few pairs in a hundred, and every pair made it (about 0.4 ms of the
        images' 6 on the bench video). The keyframe made of a view keeps it, so ``plain_left`` stays with it."""
        coarse, factor = self.plain_left, 1
        while coarse.shape[1] > COARSE_MAX_WIDTH:
            coarse, factor = cv2.pyrDown(coarse), 2 * factor
        return band_pass(coarse), factor


@dataclass(eq=False)
class View:
    """One pair at the working scale: band-passed grey images (:func:`band_pass`), where features may be taken or
    followed (``mask`` left, ``right_mask``; 255: tissue, 0: the probe or the border), how textured it is (the left
    band-pass's mean deviation, grey levels) and how sharp (that per grey level of brightness, so a brighter or
    darker light does not count as sharper or blurred); ``coarse``: the left image band-passed
    ``coarse_factor`` times smaller (at most ``COARSE_MAX_WIDTH`` wide), with its mask, for
    :mod:`snreg.odometry.search`, made when first asked for from the pair's ``images``."""

    left: np.ndarray
    right: np.ndarray
    mask: np.ndarray
    right_mask: np.ndarray
    texture: float
    contrast: float
    images: PairImages

    @classmethod
    def of(cls, pair: EyePair, left: np.ndarray, right: np.ndarray, params: OdometryParams,
           probe_tip: np.ndarray | None = None, probe_axis: np.ndarray | None = None,
           probe: ProbeModel | None = None, *, images: PairImages | None = None) -> "View":
        """The view of a BGR pair; with the probe's tip and axis (left camera frame, mm) and model, the probe and a
        margin about it are left out of the mask. ``images``: the pair's :class:`PairImages` made already (beside
        the probe tracker), else made here."""
        images = images if images is not None else PairImages.of(pair, left, right)
        masks = [np.zeros(images.left.shape, np.uint8) for _ in range(2)]
        b = params.border_px
        for eye, mask in enumerate(masks):
            mask[b:-b, b:-b] = 255
            if probe_tip is not None and probe_axis is not None and probe is not None:
                _cut_probe(mask, pair, eye, np.asarray(probe_tip, float), np.asarray(probe_axis, float), probe,
                           params.lk_window_px // 2 + 3)
        tissue = masks[0][::2, ::2] > 0
        texture = float(images.deviation[tissue].mean()) / _GAIN if tissue.any() else 0.0
        contrast = texture / max(images.brightness, 1.0)
        return cls(images.left, images.right, masks[0], masks[1], texture, contrast, images)

    @property
    def coarse_factor(self) -> int:
        return self.images.coarse[1]

    @cached_property
    def coarse_mask(self) -> np.ndarray:
        coarse = self.images.coarse[0]
        return cv2.resize(self.mask, (coarse.shape[1], coarse.shape[0]), interpolation=cv2.INTER_NEAREST)

    @cached_property
    def coarse(self) -> np.ndarray:
        coarse, coarse_mask = self.images.coarse[0], self.coarse_mask
        # the probe's strong edges would outweigh the tissue: left out where known, limited everywhere
        limit = 3.0 * max(float(cv2.absdiff(coarse, _MID)[coarse_mask > 0].mean()), 1.0) if coarse_mask.any() else 1.0
        coarse = np.clip(coarse, _MID - limit, _MID + limit).astype(np.uint8)
        coarse[coarse_mask == 0] = _MID
        return coarse


@dataclass(eq=False)
class Keyframe:
    """Tissue points (N, 3, left camera frame, mm) of one pair with where they are in it (working pixels, both
    eyes), the pair's band-passed images (and the coarse left one with its mask, made when first asked for: from the
    ``view`` it was made of), its camera rotation (``trocar_from_camera``, 3 x 3: the IMU's at the first, the motion
    fit's after), insertion (mm) and that insertion's variance (mm², from the keyframes it was measured from), and its
    contrast."""

    number: int
    frame: int
    points: np.ndarray
    left_px: np.ndarray
    right_px: np.ndarray
    left: np.ndarray
    right: np.ndarray
    rotation: np.ndarray
    insertion_mm: float
    variance_mm2: float
    contrast: float
    view: View = field(repr=False)
    centre: np.ndarray = field(init=False)       # the points' median (3,), mm
    _warps: dict = field(init=False, default_factory=dict, repr=False)

    def __post_init__(self):
        self.centre = np.median(self.points, axis=0)

    def warped(self, eye: int, homography: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """The image of eye 0 or 1 warped by ``homography`` to ``size`` (width, height); the last warp again when it
        moves no pixel by more than a hundredth of one from this one (a camera at rest costs no warp)."""
        width, height = size
        corners = np.array([[[0.0, 0.0]], [[width, 0.0]], [[0.0, height]], [[width, height]]])
        last = self._warps.get(eye)
        if last is not None and last[2] == size and np.abs(cv2.perspectiveTransform(corners, homography)
                                                            - cv2.perspectiveTransform(corners, last[0])).max() < 0.01:
            return last[1]
        image = cv2.warpPerspective(self.left if eye == 0 else self.right, homography, size, flags=cv2.INTER_LINEAR,
                                    borderMode=cv2.BORDER_CONSTANT, borderValue=_MID)
        self._warps[eye] = (homography, image, size)
        return image

    @property
    def coarse(self) -> np.ndarray:
        return self.view.coarse

    @property
    def coarse_mask(self) -> np.ndarray:
        return self.view.coarse_mask

    @property
    def median_depth_mm(self) -> float:
        return float(self.centre[2])


def make_keyframe(pair: EyePair, view: View, params: OdometryParams, *, number: int, frame: int,
                  rotation: np.ndarray, insertion_mm: float, variance_mm2: float,
                  depth_guess_mm: float = 80.0, matched: tuple[np.ndarray, np.ndarray] | None = None,
                  corners: np.ndarray | None = None) -> Keyframe | None:
    """A keyframe of ``view`` (None when fewer than ``params.min_points`` tissue points could be triangulated).

    ``matched``: points of this very pair already matched left to right (working pixels (M, 2) in each eye: those the
    motion fit agreed with). Each corner is then looked for at the disparity of the nearest of them, a few hundredths
    of a pixel off at the median on the bench video, and matched on the image itself both ways (``ACROSS_LEVELS``)
    instead of from ``depth_guess_mm`` over a 5-level pyramid (issue 36: a keyframe pair's stereo match was a third of
    what it cost over the pairs between keyframes). ``corners``: :func:`keyframe_corners` of ``view`` when found
    already (a pair earlier: the tracker spreads a keyframe's work over two pairs)."""
    left_px = keyframe_corners(view, params) if corners is None else corners
    if left_px is None:
        return None
    if matched is not None and len(matched[0]) >= _MIN_MATCHED:
        nearest = cKDTree(matched[0]).query(left_px)[1]
        guess, levels = left_px + (matched[1] - matched[0])[nearest], (ACROSS_LEVELS, ACROSS_LEVELS)
    else:
        guess = pair.project(np.column_stack([pair.normalise(left_px, 0), np.ones(len(left_px))]) * depth_guess_mm, 1)
        levels = (4, 1)
    right_px, found = lucas_kanade(view.left, view.right, left_px, guess.astype(np.float32), params, levels=levels[0])
    back, found_back = lucas_kanade(view.right, view.left, right_px, left_px.copy(), params, levels=levels[1])
    good = found & found_back & (np.linalg.norm(back - left_px, axis=1) < 0.5)
    good &= (pair.epipolar_gap_px(left_px, right_px) < 0.75) & inside(view.right_mask, right_px)
    if good.sum() < params.min_points:
        return None
    left_px, right_px = left_px[good], right_px[good]
    points = pair.triangulate(pair.normalise(left_px, 0), pair.normalise(right_px, 1))
    ahead = (points[:, 2] > 5.0) & (points[:, 2] < 1000.0)
    if ahead.sum() < params.min_points:
        return None
    return Keyframe(number, frame, points[ahead], left_px[ahead], right_px[ahead], view.left, view.right,
                    np.asarray(rotation, float), float(insertion_mm), float(variance_mm2), view.contrast, view)


def keyframe_corners(view: View, params: OdometryParams) -> np.ndarray | None:
    """(N, 2) float32 tissue corners of the view's left image a keyframe is made of (Shi-Tomasi, on the mask, the
    strongest first), or None when fewer than ``params.min_points``."""
    corners = cv2.goodFeaturesToTrack(view.left, params.max_features, 0.005, params.min_distance_px, mask=view.mask,
                                      blockSize=7)
    if corners is None or len(corners) < params.min_points:
        return None
    return corners.reshape(-1, 2).astype(np.float32)


def inside(mask: np.ndarray, px: np.ndarray) -> np.ndarray:
    """(N,) whether each working pixel (N, 2) falls on a 255 of ``mask``."""
    height, width = mask.shape
    col, row = np.round(px[:, 0]), np.round(px[:, 1])
    ok = np.isfinite(px).all(axis=1) & (col >= 0) & (col < width) & (row >= 0) & (row < height)
    out = np.zeros(len(px), bool)
    out[ok] = mask[row[ok].astype(int), col[ok].astype(int)] > 0
    return out


def band_pass(grey: np.ndarray) -> np.ndarray:
    """The tissue's texture without the light: the grey image smoothed a little, less its slow variations, scaled
    about mid-grey (uint8). The endoscope's light moves with the camera, so a view's brightness changes under the
    tissue; Lucas-Kanade on the raw image follows the light by pixels, on this by a tenth of one."""
    fine = cv2.GaussianBlur(grey, (_FINE_TAPS, _FINE_TAPS), _FINE_PX)
    small = cv2.sepFilter2D(cv2.pyrDown(cv2.pyrDown(grey)), -1, _WIDE_KERNEL, _WIDE_KERNEL)    # a wide blur, cheaply
    coarse = cv2.resize(small, (grey.shape[1], grey.shape[0]), interpolation=cv2.INTER_LINEAR)
    return cv2.addWeighted(fine, _GAIN, coarse, -_GAIN, 128.0)


def follow(keyframe: "Keyframe", eye: int, after: np.ndarray, points: np.ndarray, predicted: np.ndarray,
           params: OdometryParams) -> tuple[np.ndarray, np.ndarray]:
    """Where ``points`` (N, 2) of the keyframe's image of eye 0 (left) or 1 (right) are in ``after``, predicted at
    ``predicted`` (N, 2).

    The keyframe image is first warped by the homography that carries the points to their predicted places, so the
    comparison meets the tissue at the current scale, shear and turn, and Lucas-Kanade only finds what the
    prediction missed: the tissue's fine texture decorrelates over a few percent of scale change."""
    before = keyframe.left if eye == 0 else keyframe.right
    if len(points) < 8:
        return lucas_kanade(before, after, points, predicted, params)
    homography, _ = cv2.findHomography(points.astype(np.float32), predicted.astype(np.float32), 0)
    if homography is None or not np.isfinite(homography).all():
        return lucas_kanade(before, after, points, predicted, params)
    if np.abs(homography[:2, :2] / homography[2, 2] - np.eye(2)).max() < _UNWARPED and \
            np.abs(homography[2, :2]).max() * max(after.shape) < _UNWARPED:
        return lucas_kanade(before, after, points, predicted, params)      # a shift: Lucas-Kanade needs no warp
    warped = keyframe.warped(eye, homography, (after.shape[1], after.shape[0]))
    moved = cv2.perspectiveTransform(points.reshape(-1, 1, 2).astype(np.float64), homography).reshape(-1, 2)
    return lucas_kanade(warped, after, moved.astype(np.float32), predicted, params)


def across(view: View, left_px: np.ndarray, disparity: np.ndarray,
           params: OdometryParams) -> tuple[np.ndarray, np.ndarray]:
    """Where the view's left-image points ``left_px`` (N, 2) are in its right image, from ``left_px + disparity``:
    positions and found. The left eye's follow found the motion's error; the predicted disparity is off by a pixel or
    two, so the finest level does (``ACROSS_LEVELS``) and no right image is warped (docs/method/insertion.md)."""
    return lucas_kanade(view.left, view.right, left_px, np.asarray(left_px) + disparity, params, ACROSS_LEVELS)


def lucas_kanade(before: np.ndarray, after: np.ndarray, points: np.ndarray, guess: np.ndarray,
                 params: OdometryParams, levels: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Where ``points`` (N, 2) of ``before`` are in ``after``, starting from ``guess`` (N, 2): positions and found."""
    if len(points) == 0:
        return np.empty((0, 2), np.float32), np.zeros(0, bool)
    size = params.lk_window_px
    moved, status, _ = cv2.calcOpticalFlowPyrLK(
        before, after, points.reshape(-1, 1, 2).astype(np.float32), guess.reshape(-1, 1, 2).astype(np.float32).copy(),
        winSize=(size, size), maxLevel=params.lk_levels if levels is None else levels,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, _LK_STEPS, _LK_EPS_PX), flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    moved = moved.reshape(-1, 2)
    height, width = after.shape
    inside = (moved[:, 0] >= 0) & (moved[:, 0] <= width - 1) & (moved[:, 1] >= 0) & (moved[:, 1] <= height - 1)
    return moved, status.ravel().astype(bool) & inside & np.isfinite(moved).all(axis=1)


def _cut_probe(mask: np.ndarray, pair: EyePair, eye: int, tip: np.ndarray, axis: np.ndarray, probe: ProbeModel,
               margin_px: float) -> None:
    """Zero the probe's image in eye 0's or 1's mask: its axis from the tip to its far end (or to where it passes
    the camera), as wide as the probe at each depth plus ``margin_px`` (a feature's window must not reach it)."""
    start, length = tip - 3.0 * axis, probe.length_mm + 3.0
    if axis[2] < 0 and start[2] + length * axis[2] < _NEAR_MM:          # the body passes by the camera: cut it there
        length = max((_NEAR_MM - start[2]) / axis[2], 0.0)
    samples = start + np.linspace(0.0, length, _PROBE_SAMPLES)[:, None] * axis
    samples = samples[samples[:, 2] >= _NEAR_MM]
    if len(samples) == 0:
        return
    centres = pair.project(samples, eye)
    radii = pair.focal_px * probe.radius_mm / samples[:, 2] + margin_px
    limit = 20.0 * max(mask.shape)                   # beyond this the probe is far outside the image
    drawable = np.isfinite(centres).all(axis=1) & (np.abs(centres).max(axis=1) < limit)
    centres, radii = centres[drawable], radii[drawable]
    # each sample a disc, each two neighbours joined by the quadrilateral tangent to both sides (made at once)
    along = np.diff(centres, axis=0)
    lengths = np.maximum(np.hypot(along[:, 0], along[:, 1]), 1e-9)
    normals = np.column_stack([-along[:, 1], along[:, 0]]) / lengths[:, None]
    quads = np.round(np.stack([centres[:-1] + radii[:-1, None] * normals, centres[1:] + radii[1:, None] * normals,
                               centres[1:] - radii[1:, None] * normals, centres[:-1] - radii[:-1, None] * normals],
                              axis=1)).astype(np.int32)
    discs = np.round(centres).astype(int).tolist()
    sizes = np.ceil(np.minimum(radii, limit)).astype(int).tolist()
    for k in range(len(discs)):
        cv2.circle(mask, tuple(discs[k]), sizes[k], 0, -1)
        if k:
            cv2.fillConvexPoly(mask, quads[k - 1], 0)
