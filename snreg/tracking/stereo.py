"""Probe position from a stereo pair (thesis §3.4.2, Appendix A): stripes, SGBM depth, triangulation.

Per pair: find candidate stripe groups in the left image and, on the rows they occupy and at a
disparity the working depth range allows, in the right image; map their centroids into the
rectified frame. A candidate becomes a fix only when its 3D stripe spacing, stripe width and band
diameter agree with the probe model (:mod:`snreg.tracking.plausibility`); otherwise the next is
tried, and with none left the pair has "no probe" (``TrackingError``). Three measurements:

- ``triangulation``: the stripe centroids of both eyes (``cv2.triangulatePoints`` with the
  rectified projections), corrected for the visible half-ring's offset from the axis.
- ``sgbm``: the thesis method. The rectified pair is cropped around the stripes (only the
  crop is remapped), SGBM with the Appendix A parameters runs on it over a disparity
  window centred on the triangulated disparity and no wider than the working depth range
  allows (the crop is padded on the left where the image is too narrow for the window),
  and a cylinder of the probe's radius is fitted to the stripe surface points.
- ``width``: the thesis' monocular baseline, depth from the probe's width in pixels.

Stripe axis points and their known distances from the tip give the axis and the tip by
least squares. Which end is the tip comes from the dark body: it runs on longer behind
the last stripe than in front of the first. Points leave in the left camera frame
(rectified coordinates rotated back by R1 transposed), in mm.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import cv2
import numpy as np

from snreg.camera import StereoCalibration
from snreg.errors import TrackingError
from snreg.probe import ProbeModel, default_probe_model
from snreg.tracking.cylinder import onto_cylinder
from snreg.tracking.markers import Stripes, find_stripe_candidates, stripe_cut_by_border
from snreg.tracking.plausibility import ProbeTolerances, check_flat_bands, check_shape, measure_shape

__all__ = ["ProbeFix", "SGBMParams", "StereoTracker", "TrackingError", "METHODS"]

METHODS = ("triangulation", "sgbm", "width")
MAX_CANDIDATES = 12            # candidate stripe groups tried per eye before "no probe"
_MAX_SURFACE_POINTS = 800
_NEIGHBOURS = np.stack(np.meshgrid(np.arange(-2, 3), np.arange(-2, 3)), axis=-1).reshape(-1, 2)


@dataclass(frozen=True)
class SGBMParams:
    """StereoSGBM settings of thesis Appendix A; the block size is ours (the thesis does not give it)."""

    block_size: int = 5
    window: int = 64                   # disparity window around the triangulated disparity (multiple of 16),
                                       # narrowed to what the working depth range allows
    prefilter_cap: int = 20
    uniqueness_ratio: int = 15
    speckle_window: int = 0
    speckle_range: int = 0
    p1_factor: int = 8                 # P1 = 8 * channels * block^2
    p2_factor: int = 36                # P2 = 36 * channels * block^2


@dataclass(frozen=True)
class ProbeFix:
    """A probe position in the left camera frame (mm): tip and stripe-band centre on the axis."""

    tip: np.ndarray
    centre: np.ndarray
    axis: np.ndarray
    quality: float
    method: str
    n_stripes: int

    def as_dict(self) -> dict:
        return {"tip": [round(float(v), 3) for v in self.tip], "centre": [round(float(v), 3) for v in self.centre],
                "axis": [round(float(v), 5) for v in self.axis], "quality": round(float(self.quality), 4),
                "method": self.method, "n_stripes": self.n_stripes}


class StereoTracker:
    """Find the probe in stereo pairs of one calibrated camera; rectification maps made once."""

    def __init__(self, calibration: StereoCalibration, probe: ProbeModel | None = None,
                 params: SGBMParams = SGBMParams(), method: str = "triangulation", *,
                 depth_range_mm: tuple[float, float] | None = None, tolerances: ProbeTolerances = ProbeTolerances()):
        if method not in METHODS:
            raise ValueError(f"tracking method must be one of {', '.join(METHODS)}")
        self.calibration, self.probe, self.params, self.method = calibration, probe or default_probe_model(), params, method
        self.depth_range_mm = tuple(float(v) for v in (depth_range_mm or self.probe.working_range_mm))
        if not 0 < self.depth_range_mm[0] < self.depth_range_mm[1]:
            raise ValueError(f"the depth range must be 0 < near < far mm, got {self.depth_range_mm}")
        self.tolerances = tolerances
        size = calibration.image_size
        self._maps = [cv2.initUndistortRectifyMap(K, D, R, P, size, cv2.CV_32FC1)
                      for K, D, R, P in ((calibration.K1, calibration.D1, calibration.R1, calibration.P1),
                                         (calibration.K2, calibration.D2, calibration.R2, calibration.P2))]
        self._cam_from_rect = calibration.R1.T
        self._eye_poses = ((np.zeros(3), np.zeros(3), calibration.K1, calibration.D1),
                           (cv2.Rodrigues(calibration.R)[0].ravel(), calibration.T.ravel(), calibration.K2, calibration.D2))
        fb = calibration.P1[0, 0] * calibration.baseline_mm          # disparity (px) x depth (mm)
        self._disparity_range = (fb / self.depth_range_mm[1], fb / self.depth_range_mm[0])
        self._max_disparity = int(np.ceil(self._disparity_range[1]))

    # -- public --------------------------------------------------------------
    def track(self, left: np.ndarray, right: np.ndarray) -> ProbeFix:
        """The probe position in this pair; TrackingError says why there is none ("no probe: ...").

        Candidate stripe groups of the left image are tried best first (:mod:`snreg.tracking.markers`); the
        first whose right-eye match and 3D shape agree with the probe model gives the fix
        (:mod:`snreg.tracking.plausibility`). The ``width`` method uses the left image only.
        """
        self._check(left, "left")
        self._check(right, "right")
        if self.method == "width":
            return self.marker_width(left)
        reasons = []
        for stripes_left in itertools.islice(find_stripe_candidates(left, self.probe), MAX_CANDIDATES):
            try:
                return self._track_candidate(left, right, stripes_left)
            except TrackingError as err:
                reasons.append(str(err))
        cut = next((eye for eye, image in (("left", left), ("right", right))
                    if stripe_cut_by_border(image, self.probe)), None)
        raise _no_probe(reasons, cut)

    def _track_candidate(self, left: np.ndarray, right: np.ndarray, stripes_left: Stripes) -> ProbeFix:
        """The fix from one left candidate, or TrackingError why it is not the probe."""
        stripes_right, rect_left, rect_right = self._match_right(right, stripes_left)
        disparity = rect_left[:, 0] - rect_right[:, 0]
        points = self._triangulate_axis(stripes_left.centroids, stripes_right.centroids)
        s = self._stripe_positions(points)
        shape = measure_shape(points, s, stripes_left, self.probe, lambda p: self.project(p, 0), self.calibration.P1[0, 0],
                              self.calibration.baseline_mm, self.tolerances)
        check_shape(shape, points, self.probe, self.depth_range_mm, self.tolerances)
        verdicts = self._end_verdicts(left, points)
        if len(points) == 2 and np.ptp(s) < np.ptp(self.probe.stripe_centres_mm) and False not in verdicts:
            # two neighbouring stripes are the first two only when tissue shows where the tip must end
            raise TrackingError("no probe: two neighbouring stripes seen, and which two cannot be told with the tip out "
                                "of view; show more of the probe")
        tip_first = self._tip_first(verdicts)
        if tip_first is None:       # the stripes alone read the same from either end: a guess would be 2 x 30 mm off
            raise TrackingError("no probe: which end is the tip cannot be told (both ends look alike or lie out of "
                                "view); show the tip's end")
        if self.method == "sgbm":
            surface = self._sgbm_surface(left, right, stripes_left, float(np.median(disparity)))
            points = onto_cylinder(points, surface, self.probe.radius_mm)
        return self._fit_axis(points, s, tip_first)

    def _match_right(self, right: np.ndarray, stripes_left: Stripes) -> tuple[Stripes, np.ndarray, np.ndarray]:
        """The right-eye candidate with as many stripes on the same rectified rows at a disparity the working range
        allows; returns it with both eyes' rectified centroids."""
        x0, y0, x1, y1 = stripes_left.box
        rect_left = self._rectify_points(stripes_left.centroids, 0)
        low, high = self._disparity_range
        counts = []
        for candidate in itertools.islice(find_stripe_candidates(right, self.probe, (x0 - self._max_disparity - 20, y0 - 40,
                                                                                      x1 + 20, y1 + 40)), MAX_CANDIDATES):
            counts.append(len(candidate))
            if len(candidate) != len(stripes_left):
                continue
            rect_right = self._rectify_points(candidate.centroids, 1)
            rows = np.abs(rect_left[:, 1] - rect_right[:, 1])
            tolerance = np.maximum(2.0, 0.1 * np.sqrt(np.minimum(stripes_left.areas, candidate.areas)))
            disparity = rect_left[:, 0] - rect_right[:, 0]
            if np.all(rows <= tolerance) and np.all((disparity > 0.5 * low) & (disparity < 1.5 * high)):
                return candidate, rect_left, rect_right
        if not counts:
            raise TrackingError("no probe stripe found in the right image")
        if len(stripes_left) not in counts:
            raise TrackingError(f"{len(stripes_left)} stripes in the left image but {counts[0]} in the right")
        raise TrackingError(f"left and right stripes do not match (not on the same rectified rows, or at a disparity "
                            f"outside the {low:.1f}-{high:.1f} px of the working depth range "
                            f"{self.depth_range_mm[0]:g}-{self.depth_range_mm[1]:g} mm)")

    def marker_width(self, left: np.ndarray) -> ProbeFix:
        """The thesis' marker-width baseline (§3.4.1): depth from the probe's width in pixels (pinhole).

        Candidates are tried best first; one is the probe when its stripes are bands rather than discs
        (:func:`~snreg.tracking.plausibility.check_flat_bands`), its depth lies in the working range and its
        stripes are no farther apart in the image than the model's spacing at that depth allows.
        """
        self._check(left, "left")
        reasons = []
        for stripes in itertools.islice(find_stripe_candidates(left, self.probe), MAX_CANDIDATES):
            try:
                return self._width_fix(stripes)
            except TrackingError as err:
                reasons.append(str(err))
        raise _no_probe(reasons)

    def _width_fix(self, stripes: Stripes) -> ProbeFix:
        check_flat_bands(stripes, self.tolerances)
        ys, xs = np.nonzero(stripes.labels)
        x0, y0 = stripes.box[:2]
        (cx, cy), (w, h), _ = cv2.minAreaRect(np.column_stack([xs + x0, ys + y0]).astype(np.float32))
        width_px = min(w, h) if len(stripes) > 1 else max(w, h)
        K = self.calibration.K1
        z = K[0, 0] * self.probe.diameter_mm / max(width_px, 1e-6)
        near, far = self.depth_range_mm
        if not near <= z <= far:
            raise TrackingError(f"no probe: its width puts it {z:.0f} mm away, outside the working depth range "
                                f"{near:g}-{far:g} mm")
        if len(stripes) > 1:
            gaps = np.diff(stripes.centroids @ stripes.direction)
            spacing = np.diff(self.probe.stripe_centres_mm).max() * (1 if len(stripes) == len(self.probe.stripe_centres_mm) else 2)
            allowed = K[0, 0] * spacing / z * (1.0 + self.tolerances.diameter)
            if gaps.max() > allowed:
                raise TrackingError(f"no probe: stripes {gaps.max() * z / K[0, 0]:.1f} mm apart at the depth their width "
                                    f"gives, more than the probe's {spacing:g} mm")
        centre = np.array([(cx - K[0, 2]) * z / K[0, 0], (cy - K[1, 2]) * z / K[1, 1], z])
        ray2d = np.append(stripes.direction, 0.0)
        axis = ray2d / np.linalg.norm(ray2d)
        return ProbeFix(centre - self.probe.band_centre_mm * axis, centre, axis, len(stripes) / 3.0, "width", len(stripes))

    # -- steps ---------------------------------------------------------------
    def _check(self, image: np.ndarray, eye: str) -> None:
        width, height = self.calibration.image_size
        if image is None or image.ndim != 3 or image.shape[2] != 3:
            raise TrackingError(f"the {eye} image must be a colour (BGR) image")
        if image.shape[1] != width or image.shape[0] != height:
            raise TrackingError(f"the {eye} image is {image.shape[1]}x{image.shape[0]} but the calibration is "
                                f"for {width}x{height}; use the matching calibration file")

    def _rectify_points(self, points: np.ndarray, eye: int) -> np.ndarray:
        c = self.calibration
        K, D, R, P = (c.K1, c.D1, c.R1, c.P1) if eye == 0 else (c.K2, c.D2, c.R2, c.P2)
        return cv2.undistortPoints(points.reshape(-1, 1, 2).astype(np.float64), K, D, R=R, P=P).reshape(-1, 2)

    def _to_camera(self, rect_points: np.ndarray) -> np.ndarray:
        return rect_points @ self._cam_from_rect.T

    def _triangulate(self, rect_left: np.ndarray, rect_right: np.ndarray) -> np.ndarray:
        c = self.calibration
        homog = cv2.triangulatePoints(c.P1, c.P2, rect_left.T.astype(np.float64), rect_right.T.astype(np.float64))
        return self._to_camera((homog[:3] / homog[3]).T)

    def project(self, points: np.ndarray, eye: int) -> np.ndarray:
        """Raw image pixels (N, 2) of left-camera points (N, 3) mm in the left (eye 0) or right (eye 1) image."""
        rvec, tvec, K, D = self._eye_poses[eye]
        return cv2.projectPoints(points.reshape(-1, 1, 3).astype(np.float64), rvec, tvec, K, D)[0].reshape(-1, 2)

    def _triangulate_axis(self, centroids_left: np.ndarray, centroids_right: np.ndarray) -> np.ndarray:
        """Axis points of the stripes from their image centroids in both eyes.

        A stripe's pixel centroid is the image of the visible half-ring's centroid, which
        lies pi/4 radius in front of the axis (towards that eye, perpendicular to the
        axis). Each eye sees that point from a slightly different side, so the centroids
        are shifted back by the predicted offsets and triangulated again.
        """
        origins = (np.zeros(3), -(self.calibration.R.T @ self.calibration.T.ravel()))
        raw = (centroids_left, centroids_right)
        corrected = raw
        for _ in range(3):
            points = self._triangulate(self._rectify_points(corrected[0], 0), self._rectify_points(corrected[1], 1))
            if len(points) < 2:
                return points
            axis = np.linalg.svd(points - points.mean(axis=0))[2][0]
            shifted = []
            for eye in (0, 1):
                rays = points - origins[eye]
                toward = -(rays - (rays @ axis)[:, None] * axis)
                toward /= np.linalg.norm(toward, axis=1, keepdims=True)
                offset = (np.pi / 4.0) * self.probe.radius_mm * toward
                shifted.append(raw[eye] - (self.project(points + offset, eye) - self.project(points, eye)))
            corrected = tuple(shifted)
        return self._triangulate(self._rectify_points(corrected[0], 0), self._rectify_points(corrected[1], 1))

    def _sgbm_surface(self, left, right, stripes: Stripes, disparity_guess: float) -> np.ndarray:
        """3D points (camera frame) of the visible stripe surface from SGBM on the rectified crop."""
        p = self.params
        width, height = self.calibration.image_size
        corners = np.array([[stripes.box[0], stripes.box[1]], [stripes.box[2], stripes.box[1]],
                            [stripes.box[0], stripes.box[3]], [stripes.box[2], stripes.box[3]]], float)
        rect = self._rectify_points(corners, 0)
        pad = 8
        x0, y0 = int(max(rect[:, 0].min() - pad, 0)), int(max(rect[:, 1].min() - pad, 0))
        x1, y1 = int(min(rect[:, 0].max() + pad, width)), int(min(rect[:, 1].max() + pad, height))
        low, high = self._disparity_range
        num_disp = min(p.window, 16 * int(np.ceil((high - low) / 16.0)))      # no wider than the depth range allows
        min_disp = max(int(disparity_guess) - num_disp // 2, 0)
        # SGBM leaves the first min_disp + num_disp columns without a disparity: pad on the left when the image
        # has fewer columns than that left of the stripes (narrow, e.g. standard-definition, images)
        wanted = x0 - min_disp - num_disp
        xa = max(wanted, 0)
        extra = xa - wanted
        crops = []
        for eye, image in enumerate((left, right)):
            map_x, map_y = self._maps[eye]
            crop = cv2.cvtColor(cv2.remap(image, map_x[y0:y1, xa:x1], map_y[y0:y1, xa:x1], cv2.INTER_LINEAR),
                                cv2.COLOR_BGR2GRAY)
            crops.append(cv2.copyMakeBorder(crop, 0, 0, extra, 0, cv2.BORDER_REPLICATE) if extra else crop)
        matcher = cv2.StereoSGBM_create(minDisparity=min_disp, numDisparities=num_disp, blockSize=p.block_size,
                                        P1=p.p1_factor * p.block_size**2, P2=p.p2_factor * p.block_size**2,
                                        preFilterCap=p.prefilter_cap, uniquenessRatio=p.uniqueness_ratio,
                                        speckleWindowSize=p.speckle_window, speckleRange=p.speckle_range)
        disparity = matcher.compute(crops[0], crops[1]).astype(np.float32) / 16.0
        labels = np.zeros((height, width), np.uint8)
        bx0, by0, bx1, by1 = stripes.box
        labels[by0:by1, bx0:bx1] = stripes.labels
        map_x, map_y = self._maps[0]
        rect_labels = cv2.remap(labels, map_x[y0:y1, xa:x1], map_y[y0:y1, xa:x1], cv2.INTER_NEAREST)
        if extra:
            rect_labels = cv2.copyMakeBorder(rect_labels, 0, 0, extra, 0, cv2.BORDER_CONSTANT, value=0)
        inner = cv2.erode((rect_labels > 0).astype(np.uint8), np.ones((3, 3), np.uint8))
        ys, xs = np.nonzero((inner > 0) & (disparity >= min_disp))
        if len(xs) < 20:
            raise TrackingError("too few valid disparities on the stripes")
        if len(xs) > _MAX_SURFACE_POINTS:
            keep = np.linspace(0, len(xs) - 1, _MAX_SURFACE_POINTS).astype(int)
            ys, xs = ys[keep], xs[keep]
        homog = np.column_stack([xs + xa - extra, ys + y0, disparity[ys, xs], np.ones(len(xs))]) @ self.calibration.Q.T
        return self._to_camera(homog[:, :3] / homog[:, 3:])

    def _stripe_positions(self, points: np.ndarray) -> np.ndarray:
        """(k,) model positions (mm from the tip) of the k stripe points, in the image order: all stripes, or for
        two the pair whose spacing is nearer the measured gap (neighbours, or the ends with the middle hidden)."""
        s_all = np.array(self.probe.stripe_centres_mm)
        n = len(points)
        if n == len(s_all):
            return s_all
        if n == 2:
            gap = np.linalg.norm(points[1] - points[0])
            return s_all[[0, -1]] if abs(gap - (s_all[-1] - s_all[0])) < abs(gap - (s_all[1] - s_all[0])) else s_all[:2]
        raise TrackingError(f"{n} stripe(s) seen; the axis needs at least two")

    def _fit_axis(self, points: np.ndarray, s: np.ndarray, tip_first: bool) -> ProbeFix:
        probe = self.probe
        n = len(points)
        if not tip_first:
            points = points[::-1]
        design = np.column_stack([np.ones(n), s])
        coef, *_ = np.linalg.lstsq(design, points, rcond=None)
        axis = coef[1] / np.linalg.norm(coef[1])
        tip = np.mean(points - s[:, None] * axis, axis=0)
        residual = points - (tip + s[:, None] * axis)
        rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
        quality = (n / len(probe.stripe_centres_mm)) * float(np.exp(-0.5 * (rms / 1.5) ** 2))
        return ProbeFix(tip, tip + probe.band_centre_mm * axis, axis, quality, self.method, n)

    def _end_verdicts(self, left: np.ndarray, points: np.ndarray) -> tuple[bool | None, bool | None]:
        """Is there grey probe body (True) or red tissue (False) beyond the first and the last stripe point?
        None for an end whose samples leave the image.

        Behind the last stripe the dark body runs on for ``length - last stripe`` mm; in front
        of the first it ends after ``first stripe + radius`` mm. So look at the image 28-34 mm
        beyond each end stripe (on the measured 3D axis): grey body there marks the back,
        red tissue the tip.
        """
        probe = self.probe
        u = (points[-1] - points[0]) / np.linalg.norm(points[-1] - points[0])
        gap = probe.stripe_width_mm / 2.0 + np.array([28.0, 30.0, 32.0, 34.0])
        verdicts = []
        for end, sign in ((points[0], -1.0), (points[-1], 1.0)):
            pixels = self.project(end + sign * gap[:, None] * u, 0)
            inside = (pixels[:, 0] >= 2) & (pixels[:, 0] < left.shape[1] - 3) & (pixels[:, 1] >= 2) & (pixels[:, 1] < left.shape[0] - 3)
            if not inside.all():
                verdicts.append(None)
                continue
            near = np.round(pixels).astype(int)[:, None, :] + _NEIGHBOURS[None]
            bgr = left[near[..., 1], near[..., 0]].astype(np.float32).mean(axis=1)   # 5x5 mean beats sensor noise
            red, green = bgr[:, 2], bgr[:, 1]
            verdicts.append(bool(np.mean(red - green < 0.2 * red + 2.0) > 0.5))      # grey body, not red tissue
        return verdicts[0], verdicts[1]

    @staticmethod
    def _tip_first(verdicts: tuple[bool | None, bool | None]) -> bool | None:
        """Is the first stripe point the one nearest the tip, from :meth:`_end_verdicts`? None when they cannot tell."""
        before, after = verdicts
        if before is not None and after is not None and before != after:
            return after
        if before is None and after is not None:
            return after
        if after is None and before is not None:
            return not before
        return None


def _no_probe(reasons: list[str], cut_eye: str | None = None) -> TrackingError:
    """The error for a pair without a fix: "no probe: " and why the best candidate was not the probe; when a stripe
    runs out of an image (``cut_eye``), that is why, whatever the stripes left in view showed."""
    if cut_eye is not None:
        return TrackingError(f"no probe: its stripes run out of the {cut_eye} image (a stripe cut by the edge is not "
                             "used); bring the probe further into view")
    if not reasons:
        return TrackingError("no probe stripe found in the left image")
    first = reasons[0] if reasons[0].startswith("no probe") else f"no probe: {reasons[0]}"
    return TrackingError(first + (f" ({len(reasons) - 1} other green group(s) rejected too)" if len(reasons) > 1 else ""))
