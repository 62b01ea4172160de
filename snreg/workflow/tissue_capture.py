"""The camera's poses over tissue, live for the trocar wizard and over recorded pairs for the command line.

Why: the pivot distance can be calibrated by turning the camera over tissue (:mod:`snreg.calibration.tissue_pivot`).
Its poses come from :class:`~snreg.odometry.poses.TissuePoseFollower`, which leaves the probe out of the tissue when
given the probe's fix; the probe tracker (:mod:`snreg.tracking`) sits beside the odometry and neither knows the
other, so they meet here, as in :mod:`snreg.workflow.insertion`. :func:`capture_tissue_samples` is the generator the
wizard's capture worker runs (no Qt: it lives in the core), :func:`follow_tissue` what ``snreg calibrate trocar
tissue`` runs over image files.

A live sample is a tracked pair with the IMU orientation taken right after it was read, kept when the camera has
turned at least :data:`~snreg.workflow.trocar_capture.MIN_SAMPLE_TURN_DEG` since the last sample, as the board
method keeps its samples. Every pair read is followed, kept or not: the follower needs them all.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from snreg.camera import StereoCalibration
from snreg.geometry import rotation_distance_deg
from snreg.odometry.poses import TissuePose, TissuePoseFollower
from snreg.probe import ProbeModel
from snreg.sources import FrameSource
from snreg.tracking import StereoTracker, TrackingError
from snreg.workflow.display import display_rgb
from snreg.workflow.trocar_capture import MIN_SAMPLE_TURN_DEG, paced_frames

__all__ = ["TissueSample", "TissueFrame", "Restarts", "capture_tissue_samples", "follow_tissue"]



@dataclass(frozen=True, eq=False)
class TissueSample:
    """A pose ``tissue_from_camera`` (4, 4) mm and the IMU's ``earth_from_imu`` (3, 3) and Euler angles (yaw, pitch,
    roll, degrees) taken with it, at host time ``t_host_ns``; ``start``: the follower's start it belongs to (poses of
    different starts are in different tissue frames)."""

    frame_index: int
    t_host_ns: int
    tissue_from_camera: np.ndarray
    earth_from_imu: np.ndarray
    euler_deg: tuple[float, float, float]
    start: int

    @property
    def pose(self) -> np.ndarray:
        """The camera pose (4, 4) the pivot is fitted to."""
        return self.tissue_from_camera


@dataclass(frozen=True, eq=False)
class TissueFrame:
    """One processed pair: the left image for display (RGB), the IMU angles taken with it, whether the camera's pose
    was found, and the new sample or, when there is none, ``note`` saying why."""

    index: int
    display_rgb: np.ndarray
    euler_deg: tuple[float, float, float]
    tracked: bool
    sample: TissueSample | None
    note: str


class Restarts:
    """How many times the wizard asked to start the follower afresh (Reset: a new tissue frame from the view in
    sight); the capture thread reads :attr:`count` at each pair."""

    def __init__(self):
        self.count = 0

    def restart(self) -> int:
        """Ask for a fresh start; returns the start that the samples from now on carry."""
        self.count += 1
        return self.count


def capture_tissue_samples(make_source: Callable[[], FrameSource], imu, calibration: StereoCalibration,
                           probe: ProbeModel | None, restarts: Restarts):
    """Generator: a :class:`TissueFrame` per pair read; returns the source's problem when it ends.

    ``make_source`` is called here, in the worker thread, and the source is closed here when the generator ends or
    is closed. ``imu.snapshot()`` must give ``earth_from_imu`` (3, 3) and ``euler_deg``; ``probe``: the probe model,
    tracked in each pair and left out of the tissue (None: the robust fit alone leaves it out).
    """
    source = make_source()
    tracker = StereoTracker(calibration, probe) if probe is not None else None
    start, follower, last_pose = None, None, None
    try:
        for frame in paced_frames(source):
            snapshot, t_host_ns = imu.snapshot(), time.perf_counter_ns()
            if start != restarts.count:
                start, last_pose = restarts.count, None
                follower = TissuePoseFollower(calibration, probe=probe)
            euler = tuple(float(a) for a in snapshot.euler_deg)
            pose = follower.update(frame.left, frame.right, probe_fix=_probe_fix(tracker, frame.left, frame.right))
            sample, note = None, f"tissue lost: {pose.reason}; bring the tissue seen before back into view, or Reset"
            if pose.tracked:
                turned = (float(rotation_distance_deg(pose.tissue_from_camera, last_pose)) if last_pose is not None
                          else np.inf)
                if turned >= MIN_SAMPLE_TURN_DEG:
                    sample = TissueSample(frame.index, t_host_ns, pose.tissue_from_camera,
                                          np.array(snapshot.earth_from_imu, dtype=float), euler, start)
                    last_pose, note = pose.tissue_from_camera, ""
                else:
                    note = (f"turned {turned:.1f} of {MIN_SAMPLE_TURN_DEG:g} degrees since the last sample: "
                            "keep turning")
            yield TissueFrame(frame.index, display_rgb(frame.left), euler, pose.tracked, sample, note)
        return source.problem
    finally:
        source.close()


def follow_tissue(pairs: Iterable[tuple[np.ndarray, np.ndarray]], calibration: StereoCalibration,
                  probe: ProbeModel | None) -> Iterator[TissuePose]:
    """One pose per (left, right) BGR pair, in the frame of the first pair with tissue in view; ``probe``: the probe
    model, tracked in each pair and left out of the tissue. ValueError for a pair of another size."""
    follower = TissuePoseFollower(calibration, probe=probe)
    tracker = StereoTracker(calibration, probe) if probe is not None else None
    for left, right in pairs:
        yield follower.update(left, right, probe_fix=_probe_fix(tracker, left, right))


def _probe_fix(tracker: StereoTracker | None, left: np.ndarray, right: np.ndarray):
    """The probe's fix in this pair, or None (no tracker, or the probe not found)."""
    if tracker is None:
        return None
    try:
        return tracker.track(left, right)
    except TrackingError:
        return None
