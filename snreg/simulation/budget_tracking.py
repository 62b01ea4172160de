"""The error budget's code-path draws of stereo calibration and probe tracking: rendered Firefly frames (thesis
1920x1080, Appendix A cameras) of the probe at each phantom node, tracked with the true calibration and with one
calibrated from noisy board corners.

Why: these two sources cost most (a 1080p render ~0.6 s per pose, a track ~0.2 s per frame), so each node's noise-free
render is made once per process and each draw exposes ``frames`` noisy, blurred frames of it. One draw gives, per
node, the tracking error (median fix with the true calibration minus the truth) and the calibration error (median fix
with the estimated calibration minus the median fix with the true one, on the same frames): the two add up to what a
session calibrated that way would track. The tracker's error changes over centimetres, not over the few millimetres
the pointing moves the probe, so it is measured at the node's nominal pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.camera import StereoCalibration
from snreg.demo.error_draws import PhantomGeometry
from snreg.demo.error_stages import estimate_calibration
from snreg.demo.errors import ErrorModel
from snreg.demo.renderer import ProbePose, RenderOptions, StereoRenderer
from snreg.probe import ProbeModel
from snreg.tracking.stereo import StereoTracker, TrackingError

__all__ = ["TrackingDraw", "TrackingBench"]


@dataclass(frozen=True, eq=False)
class TrackingDraw:
    """(N, 3) camera-frame errors of one draw, mm, and how many of its frames gave no fix."""

    tracking: np.ndarray
    calibration: np.ndarray
    lost_frames: int = 0


class TrackingBench:
    """The renders of one process (made on first use) and the draws tracked from them."""

    def __init__(self, cameras: StereoCalibration, probe: ProbeModel, geometry: PhantomGeometry):
        self.cameras, self.probe, self.geometry = cameras, probe, geometry
        self._renderer: StereoRenderer | None = None
        self._radiance: list = []
        self._trackers: dict[str, StereoTracker] = {}

    def _prepare(self, method: str) -> None:
        if self._renderer is None:
            self._renderer = StereoRenderer(self.cameras, self.probe)
            self._radiance = [self._renderer.radiance(ProbePose.make(tip, self.geometry.axis_camera), RenderOptions())
                              for tip in self.geometry.tips_camera]
        if method not in self._trackers:
            self._trackers[method] = StereoTracker(self.cameras, self.probe, method=method)

    def draw(self, model: ErrorModel, seed: int) -> TrackingDraw:
        """One seeded draw under ``model``'s calibration and tracking parameters."""
        t = model.values["tracking"]
        method = str(t["method"])
        self._prepare(method)
        c = model.values["calibration"]
        estimated = None
        if model.on("calibration") and c["corner_noise_px"] > 0:
            calibration = estimate_calibration(self.cameras, views=int(c["views"]), corner_noise_px=c["corner_noise_px"],
                                               seed=seed)
            estimated = StereoTracker(calibration, self.probe, method=method)
        truth = self.geometry.tips_camera
        true_fixes = np.full((len(truth), int(t["frames"]), 3), np.nan)
        est_fixes = np.full_like(true_fixes, np.nan)
        for k, radiance in enumerate(self._radiance):
            for f in range(int(t["frames"])):
                options = RenderOptions(noise_sigma=t["noise_sigma"], blur_sigma_px=t["blur_px"],
                                        seed=int(np.random.default_rng([seed, k, f]).integers(1 << 31)))
                left, right = self._renderer.expose(radiance, options)
                true_fixes[k, f] = _tip(self._trackers[method], left, right)
                if estimated is not None:
                    est_fixes[k, f] = _tip(estimated, left, right)
        lost = int(np.isnan(true_fixes[..., 0]).sum() + (np.isnan(est_fixes[..., 0]).sum() if estimated else 0))
        with np.errstate(all="ignore"):
            tracked = np.nanmedian(true_fixes, axis=1)
            tracking = np.nan_to_num(tracked - truth)
            calibration = (np.nan_to_num(np.nanmedian(est_fixes, axis=1) - tracked) if estimated is not None
                           else np.zeros_like(truth))
        return TrackingDraw(tracking, calibration, lost)


def _tip(tracker: StereoTracker, left, right) -> np.ndarray:
    """The tracked tip (3,) mm, NaN without a fix."""
    try:
        return tracker.track(left, right).tip
    except TrackingError:
        return np.full(3, np.nan)
