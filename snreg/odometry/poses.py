"""The camera's free poses over still tissue, relative to the first view of it, from the stereo video alone.

Why: turning the camera about the trocar over tissue calibrates the pivot distance with no board (issue 27, item 3;
:mod:`snreg.calibration.tissue_pivot`). That needs the camera's metric motion with no model of it: a 6-DoF pose per
pair in a frame fixed to the tissue, here the left camera frame of the first pair with tissue in view
(``tissue_from_camera``). Each pair is compared with a keyframe (:func:`~snreg.odometry.views.make_keyframe`: tissue
corners matched left to right and triangulated): the keyframe's points are followed into both eyes
(:func:`~snreg.odometry.views.follow`) from where the predicted pose puts them, and the pose is fitted to where they
are seen (:func:`fit_rigid`: both eyes, robustly, so the probe and whatever moves against the tissue drop out).

Prediction: the last pose moved on as between the last two pairs (over a few lost pairs too); when the followed
points disagree, once more from the prediction shifted by what the coarse images show
(:func:`~snreg.odometry.search.coarse_shift`); after a loss, from the last pose found as well. A new keyframe is made
from a pair when no keyframe is within ``fresh_angle_deg`` of it or the one followed kept too few of its points; its
pose is the one measured for that pair, so poses far from the first view carry the error of the keyframes between (a
few tenths of a millimetre over a 20-degree turn on rendered tissue). A keyframe point that disagrees with the motion
twice running (the probe, an instrument) is dropped from it. A pair is tracked or lost with the reason in words.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.camera import StereoCalibration
from snreg.geometry import invert, make_transform, rotation_angle_deg
from snreg.odometry.eyes import EyePair
from snreg.odometry.motion import MotionFit, Observations, _both_eyes, _rms, _rotation, _rotvec, _turn_rows
from snreg.odometry.search import MIN_RESPONSE, coarse_shift, predicted_homography
from snreg.odometry.views import Keyframe, OdometryParams, View, follow, inside, make_keyframe
from snreg.probe import ProbeModel

__all__ = ["TissuePose", "TissuePoseFollower", "fit_rigid"]

_CONVERGED = 1e-7
_HUBER_PX = (4.0, 1.0)       # the robust fit: four iterations with each Huber width (a poor start, then a good one),
_FINAL_ITERATIONS = 4        # then the inliers alone: a point's worse eye within
_CUT_MEDIANS, _CUT_PX = 3.0, (0.75, 2.0)     # this many times the median of all, within these (working pixels)
_KEPT_SHARE = 0.6            # a keyframe whose followed points fall below this share of its own is renewed
_STRIKES = 2                 # a keyframe point that disagrees this many times running is dropped
_TRIED, _SEARCHED = 2, 4     # keyframes tried from the prediction; after a loss, keyframes tried from each start
_MAX_GAP = 5                 # pairs lost over which the last motion is carried on


@dataclass(frozen=True, eq=False)
class TissuePose:
    """The camera's pose at one pair: ``tissue_from_camera`` (4, 4, mm; None when lost), the tissue points that agreed
    with it, their share of those followed, their RMS reprojection error (px at the working scale), the keyframe
    measured against (-1: none) and, when lost, the ``reason`` in words."""

    index: int
    tissue_from_camera: np.ndarray | None
    points: int = 0
    share: float = 0.0
    rms_px: float = float("nan")
    keyframe: int = -1
    reason: str = ""

    @property
    def tracked(self) -> bool:
        return self.tissue_from_camera is not None


@dataclass(eq=False)
class _Anchor:
    """A keyframe with its pose in the tissue frame and, per point, whether it is still used and how many times
    running it disagreed."""

    keyframe: Keyframe
    tissue_from_keyframe: np.ndarray
    alive: np.ndarray
    strikes: np.ndarray


def fit_rigid(obs: Observations, rotation: np.ndarray, translation: np.ndarray) -> MotionFit:
    """Rotation (3, 3) and translation (3,) mm current_from_keyframe with no model of the motion, from a start: the
    reprojection error of the keyframe's points in both current eyes minimised robustly by Gauss-Newton, as
    :func:`~snreg.odometry.motion.fit_pivot` does under the pivot model: Huber weights, then the inliers alone, cut
    at a few times the median error (the tissue's points agree to tenths of a pixel, and the probe, moving a pixel
    or two against the tissue between pairs, must not pull the pose). A start that is not quite a rotation (a
    product of many) is made one first: the fit keeps what it is given."""
    rotation = _rotation(_rotvec(np.asarray(rotation, float)))
    translation = np.asarray(translation, float).copy()
    huber = np.repeat(_HUBER_PX, 4)
    keep = np.ones(len(obs), bool)
    for iteration in range(len(huber) + _FINAL_ITERATIONS):
        turned = obs.points @ rotation.T
        values, d_q, error = _both_eyes(turned + translation, obs)
        rows = np.empty((len(turned), 4, 6))
        _turn_rows(turned, d_q, rows[:, :, :3])
        rows[:, :, 3:] = d_q
        rows = rows.reshape(-1, 6)
        final = iteration >= len(huber)
        if final:
            keep = error < np.clip(_CUT_MEDIANS * float(np.median(error)), *_CUT_PX)
            point = keep.astype(float)
        else:
            point = np.minimum(1.0, huber[iteration] / np.maximum(error, 1e-9))
        weights = np.repeat(point, 4)
        try:
            step = -np.linalg.solve(rows.T @ (rows * weights[:, None]), rows.T @ (values * weights))
        except np.linalg.LinAlgError:        # no inliers left: nothing agrees with any one motion
            keep[:] = False
            break
        rotation = _rotation(step[:3]) @ rotation
        translation = translation + step[3:]
        if final and np.abs(step).max() < _CONVERGED:
            break
    return MotionFit(rotation, translation, float("nan"), keep, float("nan"), _rms(error, keep))


class TissuePoseFollower:
    """Follow the camera of ``calibration`` over still tissue, pair by pair, as free poses in the tissue frame.

    ``probe``: the probe model, to leave the probe out of the tissue when :meth:`update` is given its fix.
    """

    def __init__(self, calibration: StereoCalibration, *, probe: ProbeModel | None = None,
                 params: OdometryParams = OdometryParams()):
        self.params, self.probe = params, probe
        self.pair = EyePair(calibration, params.work_width)
        self.anchors: list[_Anchor] = []
        self._index = -1
        self._last: tuple[int, np.ndarray] | None = None        # the last tracked pair and its pose
        self._before: tuple[int, np.ndarray] | None = None      # the one tracked before it

    def update(self, left: np.ndarray, right: np.ndarray, *, probe_fix=None) -> TissuePose:
        """The pose at this pair: BGR frames of the calibration's size; ``probe_fix``: the probe's tracked fix in
        this pair (anything with ``tip`` and ``axis`` in the left camera frame, mm), whose image is left out.
        ValueError for frames of another size."""
        self._index += 1
        tip, axis = (None, None) if probe_fix is None else (probe_fix.tip, probe_fix.axis)
        view = View.of(self.pair, left, right, self.params, tip, axis, self.probe)
        if view.texture < self.params.min_texture:
            return self._lost("no tissue texture in view (covered, dark, smoke or inside the trocar)")
        if not self.anchors:
            if self._add_anchor(view, np.eye(4)) is None:
                return self._lost("too few tissue features to start from")
            return self._tracked(TissuePose(self._index, np.eye(4), len(self.anchors[0].keyframe.points), 1.0, 0.0, 0))
        pose, reason = self._follow(view)
        if pose is None:
            return self._lost(reason)
        return self._tracked(pose, view)

    # -- steps ---------------------------------------------------------------
    def _follow(self, view: View) -> tuple[TissuePose | None, str]:
        """This pair against the keyframes nearest the predicted pose; after a loss, also against those nearest the
        last pose found."""
        gap = self._index - self._last[0]
        starts = [self._predicted(gap)] + ([self._last[1]] if gap > 1 else [])
        reasons = []
        for start in starts:
            for anchor in self._ranked(start)[:_TRIED if gap == 1 else _SEARCHED]:
                pose, reason = self._measure(view, anchor, start)
                if pose is not None:
                    return pose, ""
                reasons.append(reason)
        return None, reasons[0] if reasons else "the view matches no tissue seen before"

    def _predicted(self, gap: int) -> np.ndarray:
        """The pose expected ``gap`` pairs after the last one found: moved on as between the last two (when they were
        consecutive), for at most ``_MAX_GAP`` pairs."""
        index, last = self._last
        if self._before is None or self._before[0] != index - 1 or gap > _MAX_GAP:
            return last
        step = invert(self._before[1]) @ last
        turn = _rotation(gap * _rotvec(step[:3, :3]))
        return last @ make_transform(turn, gap * step[:3, 3])

    def _ranked(self, pose: np.ndarray) -> list[_Anchor]:
        """The keyframes to try at ``pose``: the least turned from it first (of equals, the first made)."""
        rotation = pose[:3, :3]
        return sorted(self.anchors, key=lambda a: float(rotation_angle_deg(rotation.T @ a.tissue_from_keyframe[:3, :3])))

    def _measure(self, view: View, anchor: _Anchor, predicted: np.ndarray) -> tuple[TissuePose | None, str]:
        """Follow the keyframe's points into this pair from where ``predicted`` puts them and fit the pose; when they
        disagree, once more from there shifted by what the coarse images show."""
        p, keyframe = self.params, anchor.keyframe
        if view.contrast * p.max_blur_ratio < keyframe.contrast:
            return None, (f"the view is blurred ({keyframe.contrast / view.contrast:.1f} times less sharp than the "
                          "tissue seen there before)")
        start = invert(predicted) @ anchor.tissue_from_keyframe        # current_from_keyframe
        now = keyframe.points @ start[:3, :3].T + start[:3, 3]
        guess_left, guess_right = self.pair.project(now, 0), self.pair.project(now, 1)
        usable = anchor.alive & (now[:, 2] > 1.0) & inside(view.mask, guess_left) & inside(view.right_mask, guess_right)
        if usable.sum() < p.min_points:
            return None, f"only {int(usable.sum())} tissue points of the keyframe are in view"
        reason = ""
        for shift in (np.zeros(2), None):
            if shift is None:
                homography = predicted_homography(keyframe.left_px[usable], guess_left[usable])
                if homography is None:
                    break
                shift, response = coarse_shift(view, keyframe, homography)
                if response < MIN_RESPONSE:
                    break
            left_px, found_left = follow(keyframe, 0, view.left, keyframe.left_px[usable], guess_left[usable] + shift, p)
            right_px, found_right = follow(keyframe, 1, view.right, keyframe.right_px[usable],
                                           guess_right[usable] + shift, p)
            found = found_left & found_right
            if found.sum() < p.min_points:
                reason = reason or f"only {int(found.sum())} tissue points could be followed"
                continue
            obs = Observations(keyframe.points[usable][found], self.pair.normalise(left_px[found], 0),
                               self.pair.normalise(right_px[found], 1), self.pair.right_from_left, self.pair.focal_px)
            fit = fit_rigid(obs, start[:3, :3], start[:3, 3])
            share = fit.n_inliers / len(obs)
            if fit.n_inliers >= p.min_points and share >= p.min_agreeing_share:
                self._strike(anchor, np.flatnonzero(usable)[found], fit.inliers)
                pose = anchor.tissue_from_keyframe @ invert(make_transform(fit.rotation, fit.translation))
                return TissuePose(self._index, pose, fit.n_inliers, share, fit.rms_px, keyframe.number), ""
            reason = reason or (f"only {fit.n_inliers} of {len(obs)} tissue points agree with one motion of the camera "
                                "(moving tissue, smoke or instruments)")
        return None, reason

    def _strike(self, anchor: _Anchor, used: np.ndarray, agreed: np.ndarray) -> None:
        """Count the disagreements of the keyframe's ``used`` points (indices) and drop those that keep disagreeing."""
        anchor.strikes[used] = np.where(agreed, 0, anchor.strikes[used] + 1)
        anchor.alive &= anchor.strikes < _STRIKES

    def _tracked(self, pose: TissuePose, view: View | None = None) -> TissuePose:
        """Remember the tracked ``pose`` for the prediction; make a keyframe of ``view`` when none is fresh for it."""
        self._before, self._last = self._last, (self._index, pose.tissue_from_camera)
        if view is None:
            return pose
        followed = next(a for a in self.anchors if a.keyframe.number == pose.keyframe)
        fresh = any(float(rotation_angle_deg(pose.tissue_from_camera[:3, :3].T @ a.tissue_from_keyframe[:3, :3]))
                    <= self.params.fresh_angle_deg for a in self.anchors)
        if not fresh or pose.points < _KEPT_SHARE * followed.alive.sum():
            self._add_anchor(view, pose.tissue_from_camera)
        return pose

    def _add_anchor(self, view: View, tissue_from_camera: np.ndarray) -> _Anchor | None:
        """A keyframe of ``view`` at this pose (None with too few tissue points); its right-eye points are first looked
        for at the keyframes' median depth. Its insertion fields are the insertion tracker's, unused here."""
        number = self.anchors[-1].keyframe.number + 1 if self.anchors else 0
        depth = float(np.median([np.median(a.keyframe.points[:, 2]) for a in self.anchors])) if self.anchors else 80.0
        keyframe = make_keyframe(self.pair, view, self.params, number=number, frame=self._index,
                                 rotation=tissue_from_camera[:3, :3], insertion_mm=0.0, variance_mm2=0.0,
                                 depth_guess_mm=depth)
        if keyframe is None:
            return None
        if len(self.anchors) >= self.params.max_keyframes:          # forget the oldest, never the first
            self.anchors.pop(1)
        n = len(keyframe.points)
        self.anchors.append(_Anchor(keyframe, tissue_from_camera, np.ones(n, bool), np.zeros(n, int)))
        return self.anchors[-1]

    def _lost(self, reason: str) -> TissuePose:
        return TissuePose(self._index, None, reason=reason)
