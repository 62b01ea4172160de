"""The IMU as acquisition sees it: a serial reader feeding the orientation filter, read as snapshots.

Why: samples arrive at ~208 Hz in the reader's own thread; the health display only needs the latest
orientation and the stream's health, taken at its own pace under a lock, and the loop records the raw samples
into the session (:meth:`ImuMonitor.take_samples`). A fix is mapped with the orientation at its frame's grab
time, not the latest (:meth:`ImuMonitor.orientation_at`: the last ``HISTORY_S`` seconds of fused orientations,
interpolated on the host clock), so a tracking loop that runs late still pairs each frame with its own pose.
Sample times are when each was measured, on the host clock: its device time mapped through the offset of the samples
that arrived soonest (:class:`~snreg.imu.device_clock.DeviceClock`), not its receive time, which trails by however
long the reader or the sender was kept from running (half a second in bursts on a loaded computer). A frame's time the
samples have not reached yet (grabbed an instant ago, or the IMU running late) is waited for, up to ``wait_s``, while
the IMU streams: the orientation at a frame is then never an older one for want of patience. The reader thread
only fuses and keeps each sample's quaternion as imufusion gives it: a scipy rotation per sample (208 Hz) once cost
more than the fusion itself; rotations and angles are made when a frame or the screen asks.
"""

from __future__ import annotations

import bisect
import threading
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.imu import Fusion, ImuSample, SerialImuReader
from snreg.imu.device_clock import DeviceClock
from snreg.imu.fusion import euler_of_wxyz
from snreg.imu.reader import DEFAULT_BAUD, ImuState

STALE_AFTER_S = 1.0
HISTORY_S = 2.0           # fused orientations kept for :meth:`ImuMonitor.orientation_at`
_XYZW = [1, 2, 3, 0]      # a w, x, y, z quaternion's parts in scipy's order
KEPT_SAMPLES_S = 10.0     # raw samples wait this long for :meth:`ImuMonitor.take_samples` before the oldest go
WAIT_S = 1.0              # at most this long for the samples to reach a frame's time (then the IMU turns stale)


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


@dataclass(frozen=True)
class ImuAt:
    """The orientation at one host time: ``earth_from_imu`` (3, 3), ``gap_s`` from that time to the nearest
    sample (0 for an IMU that needs no samples; inf when there are none), and the IMU's ``state``."""

    earth_from_imu: np.ndarray
    gap_s: float
    state: str

    @property
    def stale(self) -> bool:
        return self.gap_s > STALE_AFTER_S


def interpolate_orientation(times_ns: np.ndarray, quats_xyzw: np.ndarray, t_ns: int) -> tuple[np.ndarray, float]:
    """(3, 3) orientation at ``t_ns`` slerped between the samples around it (times (N,) ns ascending, quaternions
    (N, 4) x, y, z, w), the nearest sample's outside them; and the distance in s to the nearest sample."""
    if len(times_ns) == 0:
        return np.eye(3), float("inf")
    k = int(np.searchsorted(times_ns, t_ns))
    if k == 0 or k == len(times_ns):
        nearest = 0 if k == 0 else len(times_ns) - 1
        return Rotation.from_quat(quats_xyzw[nearest]).as_matrix(), abs(int(t_ns) - int(times_ns[nearest])) / 1e9
    pair = times_ns[k - 1:k + 1]
    # scipy's Slerp, step by step: building a Slerp object took most of the worker's IMU time per pair (issue 36)
    before, after = Rotation.from_quat(quats_xyzw[k - 1]), Rotation.from_quat(quats_xyzw[k])
    alpha = (float(t_ns) - float(pair[0])) / (float(pair[1]) - float(pair[0]))
    rotation = before * Rotation.from_rotvec((before.inv() * after).as_rotvec() * alpha)
    return rotation.as_matrix(), min(int(t_ns) - int(pair[0]), int(pair[1]) - int(t_ns)) / 1e9


def _time_of(entry: tuple[int, np.ndarray]) -> int:
    """A history entry's host time (ns)."""
    return entry[0]


class ImuMonitor:
    """Reads ``port`` at ``baudrate`` with :class:`SerialImuReader`, fuses every sample with :class:`Fusion`;
    thread-safe :meth:`snapshot`; :meth:`orientation_at` waits up to ``wait_s`` for the samples to reach a time.
    ``device_rate``: device seconds per host second (a recording replayed ``speed`` times faster: ``speed``)."""

    def __init__(self, port: str, sample_rate_hz: float = 208.0, *, baudrate: int = DEFAULT_BAUD,
                 wait_s: float = WAIT_S, device_rate: float = 1.0):
        self._lock = threading.Lock()
        self._arrived = threading.Condition(self._lock)     # notified at each sample
        self._clock = DeviceClock(rate=device_rate)
        self.wait_s = float(wait_s)
        self.waiting = 0                                     # calls of orientation_at waiting for a sample now
        self._fusion = Fusion(sample_rate_hz)
        self._pending: deque[ImuSample] = deque(maxlen=int(sample_rate_hz * KEPT_SAMPLES_S))
        # (host time measured ns, fused quaternion w, x, y, z as imufusion gives it) per sample, oldest first: the
        # orientations to interpolate, the latest orientation and the measured rate
        self._history: deque[tuple[int, np.ndarray]] = deque(maxlen=int(sample_rate_hz * HISTORY_S))
        self._reader = SerialImuReader(port, baudrate, on_sample=self._on_sample)
        self.started = False

    def start(self) -> "ImuMonitor":
        self._reader.start()
        self.started = True
        return self

    def stop(self) -> None:
        self._reader.stop()
        with self._lock:
            self._arrived.notify_all()          # a call waiting for a sample: there will be none

    def _on_sample(self, sample: ImuSample) -> None:
        # 208 times a second in the reader thread: the quaternion only; rotations and angles when someone asks
        self._fusion.advance(sample)
        quat = self._fusion.quaternion_wxyz
        measured = self._clock.host_ns(sample.t_device_us, sample.t_host_ns)
        with self._lock:
            self._pending.append(sample)
            self._history.append((measured, quat))
            self._arrived.notify_all()

    def orientation_at(self, t_host_ns: int) -> ImuAt:
        """The fused orientation at host time ``t_host_ns`` (a frame's grab time), interpolated between samples;
        while no sample has reached that time yet and the IMU streams, waits for one up to ``wait_s``."""
        deadline = time.monotonic() + self.wait_s
        with self._lock:        # the two samples around it (one at either end), found by bisection, not copied all
            while (not self._history or self._history[-1][0] < t_host_ns) and self._streaming():
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self.waiting += 1
                try:
                    self._arrived.wait(left)
                finally:
                    self.waiting -= 1
            k = bisect.bisect_left(self._history, t_host_ns, key=_time_of)
            around = [self._history[i] for i in range(max(k - 1, 0), min(k + 1, len(self._history)))]
        times = np.array([t for t, _ in around], dtype=np.int64)
        quats = np.array([q for _, q in around]).reshape(-1, 4)[:, _XYZW]
        earth_from_imu, gap_s = interpolate_orientation(times, quats, t_host_ns)
        return ImuAt(earth_from_imu, gap_s, self._reader.state.value)

    def _streaming(self) -> bool:
        """The reader receives samples (not stopped, unplugged or stale): worth waiting for."""
        return self._reader.state is ImuState.STREAMING

    def take_samples(self) -> list[ImuSample]:
        """The raw samples received since the last call (at most the last ``KEPT_SAMPLES_S`` seconds), for recording."""
        with self._lock:
            samples = list(self._pending)
            self._pending.clear()
        return samples

    def snapshot(self) -> ImuSnapshot:
        now = time.perf_counter_ns()
        with self._lock:
            recent = len(self._history) - bisect.bisect_left(self._history, now - 1_000_000_000, key=_time_of)
            last = self._history[-1] if self._history else None
        age_s = (now - last[0]) / 1e9 if last else float("inf")
        state = self._reader.state
        counts = self._reader.counts
        earth_from_imu = Rotation.from_quat(last[1][_XYZW]).as_matrix() if last else np.eye(3)
        euler = tuple(float(angle) for angle in euler_of_wxyz(last[1][None])[0]) if last else (0.0, 0.0, 0.0)
        return ImuSnapshot(state.value, self._reader.problem, float(recent), age_s, euler, earth_from_imu,
                           counts.samples, counts.corrupt)
