"""The step that tracks one stereo pair: the probe's fix (or why there is none), then the camera's insertion with
that fix. One function, run wherever the pair is tracked: in the acquisition's own thread, in the tracking process
of the live loop (:mod:`snreg.workflow.tracking_process`, issue 36), and over recorded pairs
(:func:`~snreg.workflow.insertion.follow_insertion`), so every path gives the very same fixes and estimates.

Beside the probe tracker, not after it (issue 36): the part of a pair's insertion that needs neither the probe's fix
nor the tracker's state (the pair's band-passed images, :meth:`~snreg.odometry.InsertionTracker.prepare`) is made in
a thread of its own (``snreg-insertion``) while the probe is tracked (OpenCV releases the GIL); the update that needs
the fix follows, in frame order.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from snreg.odometry import InsertionEstimate, InsertionTracker
from snreg.tracking import ProbeFix, StereoTracker, TrackingError

__all__ = ["TrackedPair", "track_pair"]


@dataclass(frozen=True, eq=False)
class TrackedPair:
    """What tracking one pair gave: the probe's ``fix`` (None with the tracker's ``reason``), the insertion tracker's
    ``estimate`` (None when the insertion is not tracked), the probe tracker's wall time and what the insertion added
    after it (ms)."""

    fix: ProbeFix | None
    reason: str
    estimate: InsertionEstimate | None
    track_ms: float
    insertion_ms: float = 0.0


def track_pair(tracker: StereoTracker, insertion: InsertionTracker | None, left: np.ndarray, right: np.ndarray,
               earth_from_imu: np.ndarray) -> TrackedPair:
    """Track the probe on the (left, right) BGR pair, then, with ``insertion``, the camera's insertion at the IMU's
    ``earth_from_imu`` (3, 3) with the probe's fix left out of the tissue. Errors other than the probe's
    :class:`~snreg.tracking.TrackingError` (a pair of another size than the calibration's) are raised."""
    images = _BESIDE.submit(insertion.prepare, left, right) if insertion is not None else None
    started = time.perf_counter()
    fix, reason = None, ""
    try:
        fix = tracker.track(left, right)
    except TrackingError as err:
        reason = str(err)
    track_ms = (time.perf_counter() - started) * 1e3
    if insertion is None:
        return TrackedPair(fix, reason, None, track_ms)
    started = time.perf_counter()
    estimate = insertion.update(left, right, earth_from_imu, probe_fix=fix, images=images.result())
    return TrackedPair(fix, reason, estimate, track_ms, (time.perf_counter() - started) * 1e3)


# the one thread a process makes its pairs' images in (started on first use, idle between pairs): one thread keeps
# the pairs in order, and one acquisition runs at a time
_BESIDE = ThreadPoolExecutor(max_workers=1, thread_name_prefix="snreg-insertion")
