"""The camera's insertion through the trocar, pair by pair, from the stereo video, the IMU and the pivot.

Why: the chain maps a stored node through the pivot-to-camera distance (``trocar_camera_mm``), which the thesis
measured once; in surgery the camera slides (issue 27). :class:`InsertionTracker` follows it: each pair's tissue
points are compared with a keyframe's (:mod:`snreg.odometry.views`) and the motion between them is fitted with the
IMU's rotation and the pivot, one unknown beside a small rotation correction (:func:`~snreg.odometry.motion.fit_pivot`);
a free fit beside it measures how far the camera is from the pivot model (``residual_mm``).

Keyframes: the one followed is the usable keyframe (scale and turn close to the view) whose insertion is known
best, so returning to an earlier view returns to that view's insertion instead of one carried through many steps;
a new keyframe is made when none is fresh (its corners found at that pair, matched across before the next is
compared: its work spread over two pairs). The comparison starts from the insertion predicted from the last two
pairs; when it fails, the insertion is searched for (:mod:`snreg.odometry.search`) near the prediction, then, as after
a lost view, along every keyframe of a similar turn. Each pair is ``tracked`` with a
quality (the share of followed tissue points that agree with the motion) and a standard error, or ``lost`` with
the reason in words: never a guess (a motion fit that fails, :attr:`~snreg.odometry.motion.MotionFit.failure`,
loses the pair too). The first pair with tissue in view becomes the first keyframe at the start insertion (the trocar
calibration's distance, or the caller's): tracked with the start's own sd and saying it is the start
(:data:`START_REASON`). Every tracked insertion's sd is the start's and the change's since together (the change's
alone: ``change_sd_mm``, what the node covariance adds to the trocar calibration's own term). While lost, the
insertion held from the last tracked pair grows uncertain as :mod:`snreg.odometry.held` says.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.camera import StereoCalibration
from snreg.chain import THESIS_TROCAR_CAMERA_SD_MM, ChainCalibration
from snreg.geometry import rotation_angle_deg
from snreg.odometry.motion import Observations, fit_free, fit_pivot, pivot_departure_mm
from snreg.odometry.search import MIN_RESPONSE, coarse_shift, predicted_homography, search_insertion
from snreg.odometry.eyes import EyePair
from snreg.odometry.views import (Keyframe, OdometryParams, PairImages, View, across, follow, inside,
                                  keyframe_corners, make_keyframe)
from snreg.probe import ProbeModel

__all__ = ["TRACKED", "LOST", "START_REASON", "InsertionEstimate", "InsertionTracker"]

TRACKED, LOST = "tracked", "lost"
START_REASON = "start: the trocar calibration's insertion"      # the first pair's word: assumed, not measured
_MAX_PREDICTED_MM = 10.0     # the prediction never runs further from the last insertion
_SEARCH_STEP = 0.015         # candidate insertions this share of the tissue's depth apart
_NEAR_STEPS = 8              # candidates on each side of the prediction
_MAX_SEARCHED = 4            # keyframes searched whole when the view is lost (one per pair, in turn)
_RECENT_PAIRS = 5            # the last insertion is searched about this long after it was measured
# the fit's standard error assumes independent feature errors, which neighbouring Lucas-Kanade windows are not:
# doubled, 94 % of the errors lie within two and 73 % within one (rendered videos, half HD, seeds 11-13)
_SD_INFLATION = 2.0


@dataclass(frozen=True)
class InsertionEstimate:
    """The camera's distance from the pivot at one pair (``trocar_camera_mm``, NaN when lost), its ``state``
    ("tracked" | "lost"), ``quality`` (share of the followed tissue points that agree, 0 when lost), ``sd_mm`` (its
    standard error: the start's and the change's since together; NaN when lost), ``residual_mm`` (the free fit's
    distance from the pivot model: a moved pivot or an IMU that is off), ``reason`` (why lost, in words; the first
    pair's :data:`START_REASON`), the points that agreed, the keyframe followed (-1: none) and ``change_sd_mm`` (the
    standard error of the change since the start alone: 0 at the start)."""

    index: int
    state: str
    trocar_camera_mm: float
    quality: float
    sd_mm: float
    residual_mm: float
    reason: str = ""
    points: int = 0
    keyframe: int = -1
    change_sd_mm: float = float("nan")

    @property
    def tracked(self) -> bool:
        return self.state == TRACKED

    def as_dict(self) -> dict:
        """JSON-ready, as ``snreg track-camera --json`` prints each frame (null for NaN)."""
        def number(value, digits):
            return round(float(value), digits) if np.isfinite(value) else None
        return {"index": self.index, "trocar_camera_mm": number(self.trocar_camera_mm, 3), "state": self.state,
                "quality": round(float(self.quality), 3), "residual_mm": number(self.residual_mm, 3),
                "sd_mm": number(self.sd_mm, 3), "change_sd_mm": number(self.change_sd_mm, 3), "reason": self.reason}


@dataclass(frozen=True)
class _Step:
    """A pair measured against one keyframe."""

    insertion_mm: float
    sd_mm: float
    residual_mm: float
    quality: float
    points: int
    depth_mm: float          # median depth of the agreeing points now
    keyframe: Keyframe
    rotation: np.ndarray     # (3, 3) the camera's trocar_from_camera rotation now, as the motion fit says
    kept: float              # of the keyframe's points in view, how many agree (``points`` scaled up by the share
    #                          followed when not all were: :meth:`InsertionTracker._followed`)
    matched: tuple[np.ndarray, np.ndarray] | None = None   # the agreeing points' working pixels now, left and right


class InsertionTracker:
    """Follow the insertion of the camera of ``calibration`` on the trocar chain ``chain`` over consecutive pairs.

    ``start_mm``: the insertion at the first pair with tissue in view (default: the chain's ``trocar_camera_mm``),
    ``start_sd_mm`` its standard error (default: the thesis' trocar calibration's, Table 3);
    ``probe``: the probe model, to leave the probe out of the tissue when :meth:`update` is given its fix.
    """

    def __init__(self, calibration: StereoCalibration, chain: ChainCalibration, *, start_mm: float | None = None,
                 start_sd_mm: float = THESIS_TROCAR_CAMERA_SD_MM, probe: ProbeModel | None = None,
                 params: OdometryParams = OdometryParams()):
        self.params, self.probe = params, probe
        self.pair = EyePair(calibration, params.work_width)
        self.shaft = chain.shaft_camera
        self._camera_from_imu = chain.imu_from_camera[:3, :3]
        self._trocar_from_earth = chain.trocar_from_earth[:3, :3]
        self.start_mm = float(chain.trocar_camera_mm if start_mm is None else start_mm)
        if not np.isfinite(self.start_mm) or self.start_mm <= 0:
            raise ValueError(f"the start insertion must be a positive distance in mm, got {start_mm}")
        self.start_sd_mm = float(start_sd_mm)
        if not (np.isfinite(self.start_sd_mm) and self.start_sd_mm >= 0):
            raise ValueError(f"the start insertion's standard error must be a number of mm of at least 0, got "
                             f"{start_sd_mm}")
        self.keyframes: list[Keyframe] = []
        self._index = -1
        self._last: _Step | None = None          # the last tracked pair's step
        self._last_index = -1
        self._velocity = 0.0                      # mm per pair between the last two tracked pairs
        self._searched = 0                        # wide searches so far: which keyframe the next one tries
        self._pending: dict | None = None         # a keyframe whose corners were found, to be made at the next pair

    def prepare(self, left: np.ndarray, right: np.ndarray) -> PairImages:
        """The pair's images that need neither its probe fix nor this tracker's state (about a third of its cost on
        a full-HD pair, ``snreg bench``'s two insertion rows), to hand to :meth:`update`: made beside the probe
        tracker, in another thread, they cost the pair no time (OpenCV releases the GIL). ValueError for frames of
        another size than the calibration's."""
        return PairImages.of(self.pair, left, right)

    def update(self, left: np.ndarray, right: np.ndarray, earth_from_imu: np.ndarray, *,
               probe_fix=None, images: PairImages | None = None) -> InsertionEstimate:
        """The insertion at this pair: BGR frames of the calibration's size, the IMU's ``earth_from_imu`` (3, 3) at
        their grab time; ``probe_fix``: the probe's tracked fix in this pair (anything with ``tip`` and ``axis`` in
        the left camera frame, mm), whose image is left out; ``images``: :meth:`prepare` of this very pair when made
        already (the estimate is the same either way). ValueError for frames of another size."""
        self._index += 1
        if self._pending is not None:             # the last pair's keyframe, made before this pair is compared
            self._add_keyframe(**self._pending)
            self._pending = None
        rotation = self._trocar_from_earth @ np.asarray(earth_from_imu, float)[:3, :3] @ self._camera_from_imu
        tip, axis = (None, None) if probe_fix is None else (probe_fix.tip, probe_fix.axis)
        view = View.of(self.pair, left, right, self.params, tip, axis, self.probe, images=images)
        if view.texture < self.params.min_texture:
            return self._lost("no tissue texture in view (covered, dark, smoke or inside the trocar)")
        if not self.keyframes:
            return self._first(view, rotation)
        step, reason = self._follow(view, rotation)
        if step is None:
            return self._lost(reason)
        if self._last_index == self._index - 1:
            self._velocity = step.insertion_mm - self._last.insertion_mm
        else:
            self._velocity = 0.0
        self._last, self._last_index = step, self._index
        self._renew(view, rotation, step)
        return InsertionEstimate(self._index, TRACKED, step.insertion_mm, step.quality,
                                 float(np.hypot(step.sd_mm, self.start_sd_mm)), step.residual_mm, "", step.points,
                                 step.keyframe.number, step.sd_mm)

    # -- steps ---------------------------------------------------------------
    def _first(self, view: View, rotation: np.ndarray) -> InsertionEstimate:
        keyframe = self._add_keyframe(view, rotation, self.start_mm, 0.0)
        if keyframe is None:
            return self._lost("too few tissue features to start from")
        self._last = _Step(self.start_mm, 0.0, 0.0, 1.0, len(keyframe.points), keyframe.median_depth_mm, keyframe,
                           keyframe.rotation, len(keyframe.points))
        self._last_index = self._index
        return InsertionEstimate(self._index, TRACKED, self.start_mm, 1.0, self.start_sd_mm, 0.0, START_REASON,
                                 len(keyframe.points), keyframe.number, 0.0)

    def _follow(self, view: View, rotation: np.ndarray) -> tuple[_Step | None, str]:
        """This pair against the best usable keyframes from the predicted insertion; else the insertion searched for
        near the prediction, then along each keyframe of a similar turn (relocalisation)."""
        guess = self._predicted()
        usable = self._usable(view, rotation, guess)
        reasons = []
        for keyframe, predicted, left in usable:
            step, reason = self._measure(view, rotation, keyframe, guess, (predicted, left))
            if step is not None:
                return step, ""
            reasons.append(reason)
        for keyframe, candidates in self._search_plan(rotation, guess, [keyframe for keyframe, *_ in usable]):
            for found in search_insertion(self.pair, view, keyframe, rotation.T @ keyframe.rotation, self.shaft,
                                          candidates):
                step, reason = self._measure(view, rotation, keyframe, found)
                if step is not None:
                    return step, ""
                reasons.append(reason)
        return None, reasons[0] if reasons else "the view matches no tissue seen before at this turn"

    def _predicted(self) -> float:
        """The insertion expected now: the last one, moving on as it moved between the last two tracked pairs."""
        last = self._last
        pairs = self._index - self._last_index
        return last.insertion_mm + float(np.clip(self._velocity * pairs, -_MAX_PREDICTED_MM, _MAX_PREDICTED_MM))

    def _search_plan(self, rotation: np.ndarray, guess: float, usable: list[Keyframe]):
        """(keyframe, candidate insertions) to search: near the guess on the best usable keyframe while the last
        insertion is recent, then the whole range one keyframe of a similar turn can be followed in (one per pair, in
        turn: a long lost stretch costs each pair a bounded search, not one of every keyframe)."""
        p = self.params
        if usable and self._index - self._last_index <= _RECENT_PAIRS:
            keyframe = usable[0]
            step = _SEARCH_STEP * keyframe.median_depth_mm
            yield keyframe, guess + step * np.arange(-_NEAR_STEPS, _NEAR_STEPS + 1)
        turned = sorted((k for k in self.keyframes if rotation_angle_deg(rotation.T @ k.rotation) <= p.usable_angle_deg),
                        key=lambda k: k.variance_mm2)[:_MAX_SEARCHED]
        if turned:
            self._searched += 1
            keyframe = turned[self._searched % len(turned)]
            reach = p.search_scale * keyframe.median_depth_mm
            step = 2.0 * _SEARCH_STEP * keyframe.median_depth_mm
            yield keyframe, keyframe.insertion_mm + step * np.arange(-np.ceil(reach / step), np.ceil(reach / step) + 1)

    def _measure(self, view: View, rotation: np.ndarray, keyframe: Keyframe, guess_mm: float,
                 projected: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[_Step | None, str]:
        """Follow the keyframe's points into this pair from the motion predicted at ``guess_mm`` and fit it; when
        that fails, once more from the prediction moved by the shift the coarse images show (the IMU's error).
        ``projected``: the points predicted at ``guess_mm`` and their left pixels when made already (:meth:`_usable`)."""
        p = self.params
        if view.contrast * p.max_blur_ratio < keyframe.contrast:
            return None, (f"the view is blurred ({keyframe.contrast / view.contrast:.1f} times less sharp than the "
                          "tissue seen there before)")
        rotation_imu = rotation.T @ keyframe.rotation              # current_from_keyframe, as the IMU says
        if projected is None:
            predicted = (keyframe.points + keyframe.insertion_mm * self.shaft) @ rotation_imu.T - guess_mm * self.shaft
            projected = predicted, self.pair.project(predicted, 0)
        predicted, guess_left = projected
        guess_right = self.pair.project(predicted, 1)
        usable = (predicted[:, 2] > 1.0) & inside(view.mask, guess_left) & inside(view.right_mask, guess_right)
        if usable.sum() < p.min_points:
            return None, f"only {int(usable.sum())} tissue points of the keyframe are in view"
        in_view, usable = int(usable.sum()), self._followed(usable)
        step, reason = self._fit(view, keyframe, usable, guess_left[usable], guess_right[usable], rotation_imu,
                                 guess_mm, in_view)
        if step is not None:
            return step, ""
        homography = predicted_homography(keyframe.left_px[usable], guess_left[usable])
        if homography is not None:
            shift, response = coarse_shift(view, keyframe, homography)
            if response >= MIN_RESPONSE and np.hypot(*shift) > 1.0:
                step, _ = self._fit(view, keyframe, usable, guess_left[usable] + shift, guess_right[usable] + shift,
                                    rotation_imu, guess_mm, in_view)
        return step, "" if step is not None else reason

    def _followed(self, usable: np.ndarray) -> np.ndarray:
        """Of a keyframe's ``usable`` points (N,) bool, the ones to follow: at most ``max_followed``, the strongest."""
        usable = usable.copy()
        usable[np.flatnonzero(usable)[self.params.max_followed:]] = False     # the strongest corners come first
        return usable

    def _fit(self, view: View, keyframe: Keyframe, usable: np.ndarray, guess_left: np.ndarray,
             guess_right: np.ndarray, rotation_imu: np.ndarray, guess_mm: float,
             in_view: int) -> tuple[_Step | None, str]:
        """The keyframe's ``usable`` points followed into the left eye from where they are expected, matched across
        into the right (:func:`~snreg.odometry.views.across`, from the disparity expected), and the motion fitted;
        ``in_view``: how many of its points are in view (``usable`` may be some of them)."""
        p = self.params
        left_px, found_left = follow(keyframe, 0, view.left, keyframe.left_px[usable], guess_left, p)
        if found_left.sum() < p.min_points:
            return None, f"only {int(found_left.sum())} tissue points could be followed"
        left_px = np.where(found_left[:, None], left_px, guess_left)
        right_px, found_right = across(view, left_px, guess_right - guess_left, p)
        found = found_left & found_right
        if found.sum() < p.min_points:
            return None, f"only {int(found.sum())} tissue points could be followed"
        obs = Observations(keyframe.points[usable][found], self.pair.normalise(left_px[found], 0),
                           self.pair.normalise(right_px[found], 1), self.pair.right_from_left, self.pair.focal_px)
        fit = fit_pivot(obs, rotation_imu, self.shaft, keyframe.insertion_mm, guess_mm,
                        rotation_sd_deg=p.rotation_sd_deg, noise_px=p.noise_px)
        if fit.failure:
            return None, fit.failure
        share = fit.n_inliers / len(obs)
        if fit.n_inliers < p.min_points or share < p.min_agreeing_share:
            return None, (f"only {fit.n_inliers} of {len(obs)} tissue points agree with the camera's motion "
                          "(moving tissue, smoke or instruments)")
        sd = float(np.sqrt((_SD_INFLATION * fit.sd_mm) ** 2 + keyframe.variance_mm2))
        if not sd <= p.max_sd_mm:
            return None, f"the insertion is uncertain (standard error {sd:.1f} mm)"
        free = fit_free(obs, fit.rotation, fit.translation, fit.inliers)
        if free.failure:
            return None, f"{free.failure}, so the camera's departure from the pivot model is unknown"
        residual = pivot_departure_mm(free, rotation_imu, self.shaft, keyframe.insertion_mm)
        now = obs.points[fit.inliers] @ fit.rotation.T + fit.translation
        return _Step(fit.insertion_mm, sd, residual, share, fit.n_inliers, float(np.median(now[:, 2])), keyframe,
                     keyframe.rotation @ fit.rotation.T, fit.n_inliers * in_view / int(usable.sum()),
                     (left_px[found][fit.inliers], right_px[found][fit.inliers])), ""

    def _usable(self, view: View, rotation: np.ndarray, insertion_mm: float,
                wanted: int = 2) -> list[tuple[Keyframe, np.ndarray, np.ndarray]]:
        """The best ``wanted`` keyframes (all that are followed or searched from) close enough in scale and turn to
        follow into this view at this rotation and insertion, with enough of their points in view, the one whose
        insertion is known best first (ties: the closest); each with its points predicted now (N, 3, left camera
        frame, mm) and their left working pixels, for :meth:`_measure`.

        A keyframe's score is at least its variance and its turn's and scale's part of the closeness (its points in
        view only add to it), so keyframes are taken in that order and their points projected only while they could
        still be among the best (issue 36: this projected every keyframe in reach, several a pair); the result is the
        one scoring every keyframe gives."""
        p, candidates, scored = self.params, [], []
        for keyframe, angle, scale in zip(self.keyframes, *self._turns_and_scales(rotation, insertion_mm)):
            if angle <= p.usable_angle_deg and scale <= p.usable_scale:
                near = scale / p.usable_scale + angle / p.usable_angle_deg
                candidates.append((keyframe.variance_mm2 + (0.1 * near) ** 2, keyframe.number, near, keyframe))
        for *least, near, keyframe in sorted(candidates, key=lambda item: item[:2]):
            if len(scored) >= wanted and tuple(least) > scored[wanted - 1][:2]:
                break
            rotation_imu = rotation.T @ keyframe.rotation
            predicted = (keyframe.points + keyframe.insertion_mm * self.shaft) @ rotation_imu.T - insertion_mm * self.shaft
            left = self.pair.project(predicted, 0)
            seen = int(np.sum((predicted[:, 2] > 1.0) & inside(view.mask, left)))
            if seen >= p.min_points:
                closeness = near + 1.0 - seen / len(keyframe.points)
                scored.append((keyframe.variance_mm2 + (0.1 * closeness) ** 2, keyframe.number,
                               (keyframe, predicted, left)))
                scored.sort(key=lambda item: item[:2])
        return [found for *_, found in scored[:wanted]]

    def _turns_and_scales(self, rotation: np.ndarray, insertion_mm: float) -> tuple[list[float], list[float]]:
        """Each keyframe's turn from the camera's ``rotation`` (degrees) and the log of how much farther its tissue is
        from the camera at ``insertion_mm`` than from the keyframe (median depth, absolute): every keyframe at once,
        as this runs for each of them twice a pair."""
        relative = rotation.T @ np.array([k.rotation for k in self.keyframes])        # current_from_keyframe (K, 3, 3)
        levers = np.array([k.centre + k.insertion_mm * self.shaft for k in self.keyframes])
        now = np.einsum("kj,kj->k", relative[:, 2, :], levers) - insertion_mm * self.shaft[2]
        then = np.array([k.median_depth_mm for k in self.keyframes])
        scales = np.abs(np.log(np.maximum(now, 1.0) / np.maximum(then, 1.0)))
        return rotation_angle_deg(relative).tolist(), scales.tolist()

    def _renew(self, view: View, rotation: np.ndarray, step: _Step) -> None:
        """A new keyframe from this pair when no keyframe is fresh for it, with the camera's rotation the motion fit
        found (``step.rotation``), not the IMU's reading at this one instant: a reading off while the camera moves (the
        IMU's lag behind the grab time) would otherwise stay in every later pair's relative rotation from this
        keyframe, a pivot residual of the insertion times that error where nothing moves (issue 35).

        Its work is spread over two pairs (issue 36: a keyframe pair cost about 9 ms more than the others, and made
        the p95): its corners are found here, and it is matched across and triangulated when the next pair comes,
        before that pair is compared, so every estimate is the one making it whole here gives."""
        p = self.params
        for keyframe, angle, scale in zip(self.keyframes, *self._turns_and_scales(rotation, step.insertion_mm)):
            if angle <= p.fresh_angle_deg and scale <= p.fresh_scale and (
                    keyframe is not step.keyframe or step.kept >= 0.6 * len(keyframe.points)):
                return
        corners = keyframe_corners(view, p)
        if corners is not None:
            self._pending = dict(view=view, rotation=step.rotation, insertion_mm=step.insertion_mm,
                                 variance_mm2=step.sd_mm**2, depth_mm=step.depth_mm, matched=step.matched,
                                 frame=self._index, corners=corners)

    def _add_keyframe(self, view: View, rotation: np.ndarray, insertion_mm: float, variance_mm2: float,
                      depth_mm: float = 80.0, matched: tuple[np.ndarray, np.ndarray] | None = None,
                      frame: int | None = None, corners: np.ndarray | None = None) -> Keyframe | None:
        """A keyframe of ``view`` (the pair ``frame``, default this one) added, the least certain forgotten beyond
        ``max_keyframes``; ``matched`` and ``corners`` as :func:`~snreg.odometry.views.make_keyframe` takes them."""
        number = self.keyframes[-1].number + 1 if self.keyframes else 0
        keyframe = make_keyframe(self.pair, view, self.params, number=number,
                                 frame=self._index if frame is None else frame, rotation=rotation,
                                 insertion_mm=insertion_mm, variance_mm2=variance_mm2, depth_guess_mm=depth_mm,
                                 matched=matched, corners=corners)
        if keyframe is None:
            return None
        if len(self.keyframes) >= self.params.max_keyframes:      # forget the least certain, never the first
            worst = max(self.keyframes[1:], key=lambda k: (k.variance_mm2, -k.number))
            self.keyframes.remove(worst)
        self.keyframes.append(keyframe)
        return keyframe

    def _lost(self, reason: str) -> InsertionEstimate:
        nan = float("nan")
        return InsertionEstimate(self._index, LOST, nan, 0.0, nan, nan, reason)
