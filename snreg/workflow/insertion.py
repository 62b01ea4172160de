"""The camera's insertion over a recorded sequence of pairs: the probe found in each (to leave it out of the tissue)
and the insertion tracked, as ``snreg track-camera`` and a session's re-tracking run it.

Why here: following the insertion needs both the probe tracker (:mod:`snreg.tracking`) and the insertion tracker
(:mod:`snreg.odometry`), which sit side by side and do not know each other.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from snreg.camera import StereoCalibration
from snreg.chain import ChainCalibration
from snreg.odometry import InsertionEstimate, InsertionTracker
from snreg.probe import ProbeModel
from snreg.tracking import StereoTracker, TrackingError

__all__ = ["follow_insertion"]


def follow_insertion(pairs: Iterable[tuple[np.ndarray, np.ndarray]], orientations: Iterable[np.ndarray],
                     calibration: StereoCalibration, chain: ChainCalibration, probe: ProbeModel, *,
                     start_mm: float | None = None) -> Iterator[InsertionEstimate]:
    """One estimate per (left, right) BGR pair, each with the IMU's ``earth_from_imu`` (3, 3) at that pair;
    ``start_mm``: the insertion at the first pair with tissue in view (default: the chain's). ValueError for a pair
    of another size than the calibration's."""
    tracker = InsertionTracker(calibration, chain, start_mm=start_mm, probe=probe)
    probe_tracker = StereoTracker(calibration, probe)
    for (left, right), earth_from_imu in zip(pairs, orientations):
        try:
            fix = probe_tracker.track(left, right)
        except TrackingError:
            fix = None
        yield tracker.update(left, right, earth_from_imu, probe_fix=fix)
