"""The camera's insertion in the workflows: followed pair by pair during acquisition (the chain of each pair and the
store guard's word on it), and over a recorded sequence of pairs as ``snreg track-camera`` and re-tracking run it.

Why here: following the insertion needs both the probe tracker (:mod:`snreg.tracking`) and the insertion tracker
(:mod:`snreg.odometry`), which sit side by side and do not know each other, and the acquisition maps every pair
through the chain at that pair's insertion (docs/design.md, Data flow).

During acquisition (:class:`CameraInsertion`): each pair is mapped with the insertion tracked at it; a lost pair
with the last one tracked (before any, the tracker's start: the trocar calibration's distance), and says so. The
IMU sees every turn of the camera but not a pure slide, so while the insertion is lost the held insertion's sd grows
with the time lost and the turn since it was last tracked (:mod:`snreg.odometry.held`: each step's ``sd_mm``, what
the node covariance uses), and the store guard refuses (:meth:`CameraInsertion.store_refusal`) once that growth says
the camera may have moved: turned more than :data:`MOVED_TURN_DEG`, lost for more than :data:`MOVED_AFTER_S` (long
enough for an unseen slide), or a mix of both.

Where the trackers run (issue 36): the insertion tracker's estimate of a pair comes from
:func:`~snreg.workflow.pair_tracking.track_pair` (in the acquisition's thread, or in the live loop's tracking process,
:mod:`snreg.workflow.tracking_process`); :meth:`CameraInsertion.step` turns it into the insertion the pair is mapped
with, here, where the store guard needs it.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from snreg.camera import StereoCalibration
from snreg.chain import ChainCalibration
from snreg.geometry import rotation_angle_deg
from snreg.imu.monitor import STALE_AFTER_S
from snreg.odometry import InsertionEstimate, InsertionTracker
from snreg.odometry.held import MOVED_AFTER_S, MOVED_TURN_DEG, held_sd_mm, may_have_moved
from snreg.probe import ProbeModel
from snreg.tracking import StereoTracker
from snreg.workflow.pair_tracking import track_pair

__all__ = ["follow_insertion", "CameraInsertion", "InsertionStep", "MOVED_TURN_DEG", "MOVED_AFTER_S",
           "LARGE_RESIDUAL_MM", "insertion_text", "residual_text"]

# the camera this far off the pivot model is worth a word: a tracked pair's residual stays below 0.1 mm on rendered
# slides and turns, and an IMU 1 degree off gives about 1.5 mm (tests/surgery_frames.py, tissue about 80 mm ahead)
LARGE_RESIDUAL_MM = 1.0


@dataclass(frozen=True, eq=False)
class InsertionStep:
    """One pair's insertion: the tracker's ``estimate``, the insertion the pair is mapped with (``used_mm``: the
    estimate's when tracked, else the last tracked, or the start), the chain at that insertion, and that insertion's
    standard error: ``sd_mm`` (the start's and the change's since together: the estimate's when tracked, grown with the
    time lost and the turn since when held) and ``change_sd_mm`` (the change since the start alone, what a node's
    covariance adds to the trocar calibration's own term)."""

    estimate: InsertionEstimate
    used_mm: float
    chain: ChainCalibration
    sd_mm: float = float("nan")
    change_sd_mm: float = float("nan")

    @property
    def held(self) -> bool:
        """The pair is mapped with an insertion tracked earlier (this one is lost)."""
        return not self.estimate.tracked


class CameraInsertion:
    """The insertion during acquisition: ``tracker`` fed pair by pair (here, or in the tracking process, which hands
    it back when it ends), ``chain`` (the trocar calibration) moved to each pair's insertion, and what the store guard
    needs (the last tracked pair's grab time and IMU orientation)."""

    def __init__(self, tracker: InsertionTracker, chain: ChainCalibration):
        self.tracker, self.chain = tracker, chain
        self.start_mm = float(tracker.start_mm)
        self.last: InsertionStep | None = None
        self._known_ns: int | None = None          # grab time of the last tracked pair (the first pair before any)
        self._known_orientation: np.ndarray | None = None
        self._known_change_sd = 0.0                # the change's sd at the last tracked pair (the start's: 0)
        self._now_ns = 0
        self._now_orientation = np.eye(3)
        self._chain_at = (self.start_mm, chain.with_insertion(self.start_mm))

    def update(self, left: np.ndarray, right: np.ndarray, t_ns: int, earth_from_imu: np.ndarray,
               probe_fix=None) -> InsertionStep:
        """Track the insertion at this pair (grabbed at ``t_ns``, host clock; ``probe_fix`` left out of the tissue)
        with :attr:`tracker`, here, and give the chain to map it with (:meth:`step`)."""
        return self.step(self.tracker.update(left, right, earth_from_imu, probe_fix=probe_fix), t_ns, earth_from_imu)

    def step(self, estimate: InsertionEstimate, t_ns: int, earth_from_imu: np.ndarray) -> InsertionStep:
        """The insertion a pair grabbed at ``t_ns`` (host clock) is mapped with, from the tracker's ``estimate`` at
        it (:func:`~snreg.workflow.pair_tracking.track_pair`, wherever it ran) and the IMU's ``earth_from_imu``;
        pairs in frame order."""
        orientation = np.asarray(earth_from_imu, dtype=float)[:3, :3]
        self._now_ns, self._now_orientation = int(t_ns), orientation
        if estimate.tracked or self._known_ns is None:
            self._known_ns, self._known_orientation = int(t_ns), orientation
        if estimate.tracked:
            self._known_change_sd = float(estimate.change_sd_mm)
        used = estimate.trocar_camera_mm if estimate.tracked else (self.last.used_mm if self.last else self.start_mm)
        if used != self._chain_at[0]:
            self._chain_at = (used, self.chain.with_insertion(used))
        change = self._known_change_sd if estimate.tracked else held_sd_mm(self._known_change_sd, *self._since_known())
        self.last = InsertionStep(estimate, float(used), self._chain_at[1],
                                  float(np.hypot(change, self.tracker.start_sd_mm)), float(change))
        return self.last

    def _since_known(self) -> tuple[float, float]:
        """(seconds, degrees of the IMU's turn) since the last tracked pair (the first pair before any)."""
        return ((self._now_ns - self._known_ns) / 1e9,
                float(rotation_angle_deg(self._known_orientation.T @ self._now_orientation)))

    def store_refusal(self) -> str:
        """Why a store must wait for the insertion, in words ("" when it need not): it is lost now and the camera may
        have moved since it was last tracked (module docstring)."""
        if self.last is None or self.last.estimate.tracked:
            return ""
        lost_s, turned = self._since_known()
        if not may_have_moved(lost_s, turned):
            return ""
        reason = f" ({self.last.estimate.reason})" if self.last.estimate.reason else ""
        if turned / MOVED_TURN_DEG >= lost_s / MOVED_AFTER_S:
            moved = f"the camera turned {turned:.1f} degrees since it was last tracked"
        else:
            moved = f"it has been lost for {lost_s:.1f} s, long enough for an unseen slide"
        return (f"the camera's insertion is lost{reason} and {moved} (the insertion held is now uncertain by "
                f"{self.last.sd_mm:.1f} mm): show the tissue to the camera, or store anyway (the override is kept on "
                "record)")


def insertion_text(step: InsertionStep | None, start_mm: float) -> str:
    """The insertion in words for the screens and the live link's status, e.g. "camera 171.0 mm, +13.0 mm since
    calibration, tracked" or "camera LOST (no tissue texture ...): 171.0 mm held"; "" without tracking."""
    if step is None:
        return ""
    since = f"{round(step.used_mm - start_mm, 1) + 0.0:+.1f} mm since calibration"      # + 0.0: never "-0.0"
    if step.estimate.tracked:
        return f"camera {step.used_mm:.1f} mm, {since}, tracked"
    reason = f" ({step.estimate.reason})" if step.estimate.reason else ""
    return f"camera LOST{reason}: {step.used_mm:.1f} mm held, {since}"


def residual_text(step: InsertionStep | None, imu_gap_s: float = 0.0) -> str:
    """What a large pivot residual means, in words ("" when the pair is lost or its residual is under
    :data:`LARGE_RESIDUAL_MM`): the camera moved otherwise than about the pivot, so the chain itself is in doubt.
    ``imu_gap_s``: from the pair to the nearest IMU sample; while the IMU is silent (over ``STALE_AFTER_S``) the pair
    was fitted at an old orientation, so the residual says the camera turned unseen, not that the trocar moved."""
    if step is None or not step.estimate.tracked or not step.estimate.residual_mm > LARGE_RESIDUAL_MM:
        return ""
    off = f"the camera is {step.estimate.residual_mm:.1f} mm off the pivot model"
    if imu_gap_s > STALE_AFTER_S:
        return (f"{off}: the IMU has been silent for {imu_gap_s:.1f} s, so its turns are not seen; reconnect the "
                "IMU")
    return f"{off}: the trocar moved or the IMU is off; check both, and calibrate the trocar again if one moved"


def follow_insertion(pairs: Iterable[tuple[np.ndarray, np.ndarray]], orientations: Iterable[np.ndarray],
                     calibration: StereoCalibration, chain: ChainCalibration, probe: ProbeModel, *,
                     start_mm: float | None = None) -> Iterator[InsertionEstimate]:
    """One estimate per (left, right) BGR pair, each with the IMU's ``earth_from_imu`` (3, 3) at that pair;
    ``start_mm``: the insertion at the first pair with tissue in view (default: the chain's). ValueError for a pair
    of another size than the calibration's."""
    tracker = InsertionTracker(calibration, chain, start_mm=start_mm, probe=probe)
    probe_tracker = StereoTracker(calibration, probe)
    for (left, right), earth_from_imu in zip(pairs, orientations):
        yield track_pair(probe_tracker, tracker, left, right, earth_from_imu).estimate      # as acquisition does
