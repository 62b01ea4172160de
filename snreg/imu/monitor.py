"""The IMU as acquisition sees it: a serial reader feeding the orientation filter, read as snapshots.

Why: samples arrive at ~208 Hz in the reader's own thread; the tracking loop and the health display
only need the latest orientation and the stream's health, taken at their own pace under a lock, and
the loop records the raw samples into the session (:meth:`ImuMonitor.take_samples`).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.geometry import euler_from_rotation
from snreg.imu import Fusion, ImuSample, SerialImuReader
from snreg.imu.reader import DEFAULT_BAUD

STALE_AFTER_S = 1.0
KEPT_SAMPLES_S = 10.0     # raw samples wait this long for :meth:`ImuMonitor.take_samples` before the oldest go


@dataclass(frozen=True)
class ImuSnapshot:
    """The IMU now: state and its one-sentence problem, measured rate, age of the last sample, orientation."""

    state: str
    problem: str
    rate_hz: float
    age_s: float
    euler_deg: tuple[float, float, float]     # yaw, pitch, roll
    earth_from_imu: np.ndarray                # (3, 3)
    samples: int
    corrupt: int

    @property
    def stale(self) -> bool:
        return self.age_s > STALE_AFTER_S


class ImuMonitor:
    """Reads ``port`` at ``baudrate`` with :class:`SerialImuReader`, fuses every sample with :class:`Fusion`;
    thread-safe :meth:`snapshot`."""

    def __init__(self, port: str, sample_rate_hz: float = 208.0, *, baudrate: int = DEFAULT_BAUD):
        self._lock = threading.Lock()
        self._fusion = Fusion(sample_rate_hz)
        self._arrivals: deque[int] = deque(maxlen=int(sample_rate_hz * 2))
        self._pending: deque[ImuSample] = deque(maxlen=int(sample_rate_hz * KEPT_SAMPLES_S))
        self._rotation = Rotation.identity()
        self._reader = SerialImuReader(port, baudrate, on_sample=self._on_sample)
        self.started = False

    def start(self) -> "ImuMonitor":
        self._reader.start()
        self.started = True
        return self

    def stop(self) -> None:
        self._reader.stop()

    def _on_sample(self, sample: ImuSample) -> None:
        self._fusion.advance(sample)            # angles only when a snapshot asks: 208 Hz stays cheap
        rotation = self._fusion.rotation
        with self._lock:
            self._rotation = rotation
            self._arrivals.append(sample.t_host_ns)
            self._pending.append(sample)

    def take_samples(self) -> list[ImuSample]:
        """The raw samples received since the last call (at most the last ``KEPT_SAMPLES_S`` seconds), for recording."""
        with self._lock:
            samples = list(self._pending)
            self._pending.clear()
        return samples

    def snapshot(self) -> ImuSnapshot:
        now = time.perf_counter_ns()
        with self._lock:
            arrivals = list(self._arrivals)
            rotation = self._rotation
        recent = [t for t in arrivals if now - t <= 1_000_000_000]
        age_s = (now - arrivals[-1]) / 1e9 if arrivals else float("inf")
        state = self._reader.state
        counts = self._reader.counts
        earth_from_imu = rotation.as_matrix()
        return ImuSnapshot(state.value, self._reader.problem, float(len(recent)), age_s,
                           euler_from_rotation(earth_from_imu), earth_from_imu, counts.samples, counts.corrupt)
