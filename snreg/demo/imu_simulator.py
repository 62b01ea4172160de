"""IMU simulator: the serial protocol on a pseudo-terminal, from a motion profile or a recording.

A :class:`MotionProfile` is the ground truth: ``world_from_sensor`` orientation as a function of
time, built from segments that rotate about fixed world axes (z up; at rest and level the
accelerometer reads +1 g on z). :class:`ImuSimulator` turns it into LSM6DSOX-like readings:
gravity in the sensor frame (a rotation about the sensor's own origin: no linear acceleration),
body-frame angular rate plus a constant gyro bias, white noise at the datasheet densities
(accelerometer 75 ug/sqrt(Hz) at +-4 g, gyroscope 3.8 mdps/sqrt(Hz), high-performance mode, over
a bandwidth of ODR/2) and quantisation to the LSB of the configured full scale.
:class:`CsvReplay` plays a recorded x-io style CSV through the same path, values as recorded.
Both can inject faults (skipped samples, garbage lines) and count what a perfect reader should
report (``sent``). :class:`SimulatedPort` writes the lines, paced in real time, to the master of
a pty whose slave path a reader opens like any serial port. Everything is seeded.
"""

from __future__ import annotations

import csv
import os
import select
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.demo.imu_motion import MotionProfile, still
from snreg.demo.motion_timeline import MotionTimeline
from snreg.files import read_text_file
from snreg.imu.protocol import DEVICE_CLOCK_WRAP_US, StreamCounts, format_info, format_line

__all__ = ["SensorModel", "Faults",
           "Readings", "ImuSimulator", "CsvReplay", "SimulatedPort"]

ACCEL_LSB_MG = {2: 0.061, 4: 0.122, 8: 0.244, 16: 0.488}             # LSM6DSOX sensitivity per full scale (g)
GYRO_LSB_MDPS = {125: 4.375, 250: 8.75, 500: 17.5, 1000: 35.0, 2000: 70.0}   # (deg/s)
_CHUNK = 256                  # samples generated per block
_TIMELINE_CHUNK = 8           # with a timeline told while it plays: blocks of 40 ms, so a run sent ahead is met
_INFO_EVERY_S = 5.0           # the info line repeats, like the firmware's, so a late reader learns the rate
_MAX_LAG_S = 0.2              # further behind schedule than this (nobody reading): resume, do not burst
_SETTLE_S = 0.1               # after the port opened, before the first line
_GARBAGE_BYTES = np.frombuffer(bytes(b for b in range(256) if b not in b" \t\n\r\x0b\x0c#$"), dtype=np.uint8)
_CSV_COLUMNS = ("Time (s)", "Gyroscope X (deg/s)", "Gyroscope Y (deg/s)", "Gyroscope Z (deg/s)",
                "Accelerometer X (g)", "Accelerometer Y (g)", "Accelerometer Z (g)")


@dataclass(frozen=True)
class SensorModel:
    """LSM6DSOX-like errors. Densities per sqrt(Hz) over ODR/2; bias uniform in +-gyro_bias_max_dps per
    axis; ranges (g, deg/s) pick the LSB and the clipping; None keeps values unquantised and unclipped."""

    accel_noise_density_g: float = 75e-6
    gyro_noise_density_dps: float = 3.8e-3
    gyro_bias_max_dps: float = 0.5
    accel_range_g: int | None = 4
    gyro_range_dps: int | None = 125

    def __post_init__(self):
        if self.accel_range_g is not None and self.accel_range_g not in ACCEL_LSB_MG:
            raise ValueError(f"accelerometer range must be one of {sorted(ACCEL_LSB_MG)} g or None")
        if self.gyro_range_dps is not None and self.gyro_range_dps not in GYRO_LSB_MDPS:
            raise ValueError(f"gyroscope range must be one of {sorted(GYRO_LSB_MDPS)} deg/s or None")

    def measure(self, accel_g, gyro_dps, rate_hz: float, rng_accel, rng_gyro):
        """Noisy, quantised copies of true (N, 3) readings at ``rate_hz``."""
        bandwidth = np.sqrt(rate_hz / 2.0)
        accel = accel_g + rng_accel.standard_normal(accel_g.shape) * self.accel_noise_density_g * bandwidth
        gyro = gyro_dps + rng_gyro.standard_normal(gyro_dps.shape) * self.gyro_noise_density_dps * bandwidth
        if self.accel_range_g is not None:
            accel = _quantise(accel, ACCEL_LSB_MG[self.accel_range_g] / 1e3)
        if self.gyro_range_dps is not None:
            gyro = _quantise(gyro, GYRO_LSB_MDPS[self.gyro_range_dps] / 1e3)
        return accel, gyro


def _quantise(values, lsb):
    return np.clip(np.round(values / lsb), -32768, 32767) * lsb


@dataclass(frozen=True)
class Faults:
    """Per sample slot: ``dropout_rate`` skips it; ``garbage_rate`` emits a corrupt line (a third each:
    binary bytes before the sample, the sample truncated, the sample with a wrong checksum)."""

    dropout_rate: float = 0.0
    garbage_rate: float = 0.0

    def __post_init__(self):
        if not (0 <= self.dropout_rate <= 1 and 0 <= self.garbage_rate <= 1 and self.dropout_rate + self.garbage_rate <= 1):
            raise ValueError("dropout and garbage rates must be fractions in [0, 1] that sum to at most 1")


@dataclass(frozen=True, eq=False)
class Readings:
    """N samples: time since the start (s), device time (us, mod 2**32), accel (N, 3) g, gyro (N, 3) deg/s."""

    t_s: np.ndarray
    t_device_us: np.ndarray
    accel_g: np.ndarray
    gyro_dps: np.ndarray


class _LineSource:
    """Protocol lines from readings, with injected faults; ``sent`` counts what a perfect reader sees."""

    rate_hz: float
    decimals: int
    sensor_name: str

    def __init__(self, faults: Faults, seed: int):
        self.faults, self.seed = faults, seed
        self.sent = StreamCounts()

    def _blocks(self, motion_offset_s: float = 0.0) -> Iterator[Readings]:
        raise NotImplementedError

    def lines(self, motion_offset_s: float = 0.0) -> Iterator[tuple[float, bytes]]:
        """(seconds from the start when due, line) pairs; restarts the stream and ``sent``. ``motion_offset_s``: the
        motion's time at the stream's start (negative: the motion starts that much later); a recording ignores it."""
        rng = np.random.default_rng([self.seed, 2])
        info = format_info(self.rate_hz, self.sensor_name)
        info_every = max(1, round(_INFO_EVERY_S * self.rate_hz))
        self.sent, lost, index = StreamCounts(), 0, 0
        for block in self._blocks(motion_offset_s):
            for t_s, t_us, accel, gyro in zip(block.t_s, block.t_device_us, block.accel_g, block.gyro_dps):
                if index % info_every == 0:
                    yield t_s, info
                index += 1
                line = format_line(t_us, accel, gyro, self.decimals)
                draw = rng.random()
                if draw < self.faults.dropout_rate:
                    lost += 1
                    continue
                if draw < self.faults.dropout_rate + self.faults.garbage_rate:
                    garbage, replaces = self._garbage(line, rng)
                    self.sent = StreamCounts(self.sent.samples, self.sent.corrupt + 1, self.sent.dropped)
                    yield t_s, garbage
                    if replaces:
                        lost += 1
                        continue
                seen = self.sent.samples > 0
                self.sent = StreamCounts(self.sent.samples + 1, self.sent.corrupt, self.sent.dropped + lost * seen)
                lost = 0
                yield t_s, line

    @staticmethod
    def _garbage(line: bytes, rng) -> tuple[bytes, bool]:
        """A corrupt line, and whether it takes the sample's place."""
        kind = rng.integers(3)
        if kind == 0:
            return rng.choice(_GARBAGE_BYTES, size=rng.integers(1, 60)).tobytes() + b"\r\n", False
        body = line.rstrip(b"\r\n")
        if kind == 1:
            return body[:rng.integers(1, len(body))] + b"\r\n", True
        wrong = int(body[-2:], 16) ^ int(rng.integers(1, 256))
        return body[:-2] + b"%02X\r\n" % wrong, True


class ImuSimulator(_LineSource):
    """Simulated LSM6DSOX on a motion profile (default: still and level).

    rate_hz: output data rate; n_samples: stream length (None: endless); start_us: device time of
    the first sample (near 2**32 to exercise the wrap). ``gyro_bias_dps`` is the drawn bias. ``timeline``: the
    profile plays on this :class:`~snreg.demo.motion_timeline.MotionTimeline` (held where it holds, skipping where it
    skips; times from the motion's start), which may be told new runs while the stream plays.
    """

    sensor_name = "LSM6DSOX-sim"

    def __init__(self, profile: MotionProfile | None = None, *, rate_hz: float = 208.0,
                 sensor: SensorModel = SensorModel(), faults: Faults = Faults(), seed: int = 0,
                 n_samples: int | None = None, start_us: int = 0, timeline: MotionTimeline | None = None):
        if not rate_hz > 0:
            raise ValueError(f"sample rate must be positive, got {rate_hz} Hz")
        super().__init__(faults, seed)
        self.profile = profile or MotionProfile([still(1.0)])
        self.rate_hz, self.sensor, self.n_samples, self.start_us = float(rate_hz), sensor, n_samples, int(start_us)
        self.decimals, self.timeline = 6, timeline
        self.gyro_bias_dps = np.random.default_rng([seed, 0]).uniform(-1, 1, 3) * sensor.gyro_bias_max_dps

    def true_orientation(self, t_device_us) -> Rotation:
        """Ground-truth ``world_from_sensor`` at device time(s) (us; valid within the first 2**32 us)."""
        t_us = (np.asarray(t_device_us, dtype=np.int64) - self.start_us) % DEVICE_CLOCK_WRAP_US
        return self.profile.orientation(t_us / 1e6)

    def readings(self, n: int) -> Readings:
        """The first ``n`` readings of the stream (the values its lines carry)."""
        blocks, have = [], 0
        for block in self._blocks():
            blocks.append(block)
            have += len(block.t_s)
            if have >= n:
                break
        return Readings(*(np.concatenate([getattr(b, f) for b in blocks])[:n]
                          for f in ("t_s", "t_device_us", "accel_g", "gyro_dps")))

    def _blocks(self, motion_offset_s: float = 0.0) -> Iterator[Readings]:
        rng_accel, rng_gyro = np.random.default_rng([self.seed, 1, 0]), np.random.default_rng([self.seed, 1, 1])
        start, chunk = 0, _CHUNK if self.timeline is None else _TIMELINE_CHUNK
        while self.n_samples is None or start < self.n_samples:
            count = chunk if self.n_samples is None else min(chunk, self.n_samples - start)
            t = (start + np.arange(count)) / self.rate_hz
            motion, rate = t + motion_offset_s, 1.0
            if self.timeline is not None:
                motion, rate = self.timeline.motion_s(motion), self.timeline.rate(motion)[:, None]
            sensor_from_world = self.profile.orientation(motion).inv()
            accel = sensor_from_world.apply([0.0, 0.0, 1.0])
            gyro = sensor_from_world.apply(rate * self.profile.angular_velocity_dps(motion)) + self.gyro_bias_dps
            accel, gyro = self.sensor.measure(accel, gyro, self.rate_hz, rng_accel, rng_gyro)
            t_us = (self.start_us + np.round(t * 1e6).astype(np.int64)) % DEVICE_CLOCK_WRAP_US
            yield Readings(t, t_us, accel, gyro)
            start += count


class CsvReplay(_LineSource):
    """A recorded CSV (x-io columns ``Time (s)``, ``Gyroscope X (deg/s)`` ..., ``Accelerometer X (g)`` ...;
    others ignored) replayed as recorded: no clipping, printed with the file's decimals."""

    sensor_name = "replay"

    def __init__(self, path, *, faults: Faults = Faults(), seed: int = 0):
        super().__init__(faults, seed)
        self.path = str(path)
        text = read_text_file(path, "IMU CSV", ValueError)
        try:
            rows = list(csv.reader(text.splitlines()))
            columns = [rows[0].index(name) for name in _CSV_COLUMNS]
            text = [[row[c] for c in columns] for row in rows[1:] if row]
            values = np.array(text, dtype=float)
        except (csv.Error, IndexError, ValueError) as err:
            raise ValueError(f"{path}: not a readable IMU CSV with columns {', '.join(_CSV_COLUMNS)} ({err})") from None
        steps = np.diff(values[:, 0]) if len(values) else np.array([])
        if len(values) < 2 or not np.all(np.isfinite(values)) or np.any(steps <= 0):
            raise ValueError(f"{path}: needs at least two rows of finite numbers with increasing times")
        self.rate_hz = float(1.0 / np.median(steps))
        self.decimals = max(_decimals(v) for row in text for v in row[1:])
        t_us = np.round(values[:, 0] * 1e6).astype(np.int64) % DEVICE_CLOCK_WRAP_US
        self.readings = Readings(values[:, 0] - values[0, 0], t_us, values[:, 4:7], values[:, 1:4])

    def _blocks(self, motion_offset_s: float = 0.0) -> Iterator[Readings]:
        yield self.readings


def _decimals(text: str) -> int:
    """Digits after the point a fixed-point print needs to reproduce ``text`` ("1.5e-05" -> 6)."""
    mantissa, _, exponent = text.strip().lower().partition("e")
    return max(0, len(mantissa.partition(".")[2]) - int(exponent or 0))


class SimulatedPort:
    """A line source on a pseudo-terminal, paced in real time (``speed`` times faster).

    ``port`` is what a reader opens: ``port_link`` (a symlink to the pty slave, replaced if it
    exists) or the slave path itself. Run it in a thread with :meth:`start` / :meth:`stop` or
    blocking with :meth:`run`; closing the master is an unplug for the reader. The stream starts
    when a reader first opens the port, so it sees the profile from its start (the initial still
    period the fusion's bias estimate needs). If the reader stops reading, writing pauses once the
    pty buffer is full and resumes without a burst. ``finished`` is set when the source has run
    out; the port stays open (silent) until stopped.

    ``hold_s``: the motion starts this long after the stream, the sensor holding its first pose until then (a
    fusion's still start). ``on_start(motion_start_ns)`` is called when the stream starts with the motion's start on
    the host clock (``time.perf_counter_ns()``, the monotonic clock every process on this computer shares), so
    another process can show the same motion in step (the demo's rendered frames); the lines then stay on that
    schedule (sent late in a burst rather than shifted, should the writer fall behind).
    """

    def __init__(self, source: _LineSource, *, port_link: str | None = None, speed: float = 1.0,
                 hold_s: float = 0.0, on_start: Callable[[int], None] | None = None):
        if not speed > 0:
            raise ValueError(f"replay speed must be positive, got {speed}")
        if not hold_s >= 0:
            raise ValueError(f"the hold before the motion must be a positive number of seconds, got {hold_s}")
        if on_start is not None and speed != 1.0:
            raise ValueError("a motion shown in step with another program runs at the host clock's pace; "
                             "leave out the speed")
        if not hasattr(os, "openpty"):
            raise ValueError("the IMU simulator needs a POSIX pseudo-terminal (Linux or macOS)")
        import tty  # POSIX only, like the pty itself

        self.source, self.speed, self.link = source, float(speed), port_link
        self.hold_s, self.on_start = float(hold_s), on_start
        self.finished, self._stop = threading.Event(), threading.Event()
        self.started_ns: int | None = None          # set when the stream starts (a replay aligns its frames to it)
        self._thread: threading.Thread | None = None
        self._master, slave = os.openpty()
        tty.setraw(slave)
        self.device = os.ttyname(slave)
        os.close(slave)
        os.set_blocking(self._master, False)
        if port_link:
            try:
                self._link(port_link)
            except ValueError:
                os.close(self._master)
                raise
        self.port = port_link or self.device

    def _wait_for_reader(self) -> bool:
        """Like a board that boots when the host opens the port, start once the slave is open (on
        Linux the master reads EIO until then), then give the opener time to finish (pyserial
        flushes its input when it opens). False if stopped first."""
        while not self._stop.is_set():
            try:
                os.read(self._master, 4096)           # what the host sends is ignored
            except BlockingIOError:
                return not self._stop.wait(_SETTLE_S)
            except OSError:
                self._stop.wait(0.01)
            else:
                return not self._stop.wait(_SETTLE_S)
        return False

    def _link(self, path: str) -> None:
        """Point the symlink ``path`` at the pty (atomically, replacing an old link)."""
        if os.path.lexists(path) and not os.path.islink(path):
            raise ValueError(f"{path} exists and is not a symlink; choose another --port-link path")
        temporary = f"{path}.{os.getpid()}.tmp"
        try:
            os.symlink(self.device, temporary)
            os.replace(temporary, path)
        except OSError as err:
            raise ValueError(f"cannot create the link {path} ({err.strerror}); choose a path in a writable directory") from None

    def start(self) -> SimulatedPort:
        self._thread = threading.Thread(target=self.run, name=f"imu-sim {self.device}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop writing, close the pty (an unplug) and remove the link if it is still ours."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        if self._master >= 0:
            os.close(self._master)
            self._master = -1
        if self.link and os.path.islink(self.link) and os.readlink(self.link) == self.device:
            os.unlink(self.link)

    def __enter__(self) -> SimulatedPort:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def run(self) -> None:
        """Wait for a reader to open the port, write the source's lines on schedule until it runs
        out, then idle until :meth:`stop`."""
        if not self._wait_for_reader():
            return
        lines = self.source.lines(-self.hold_s)
        item, pending, t0 = next(lines, None), b"", time.perf_counter()
        self.started_ns = round(t0 * 1e9)           # the host time (perf_counter_ns) of the source's time 0
        if self.on_start is not None:
            self.on_start(self.started_ns + round(self.hold_s * 1e9))
        while not self._stop.is_set():
            now = time.perf_counter() - t0
            if item is not None and not pending:
                late = now - item[0] / self.speed
                if late > _MAX_LAG_S and self.on_start is None:
                    t0, now = t0 + late, now - late
                batch = []
                while item is not None and item[0] / self.speed <= now:
                    batch.append(item[1])
                    item = next(lines, None)
                pending = b"".join(batch)
            if pending:
                try:
                    pending = pending[os.write(self._master, pending):]
                except BlockingIOError:
                    select.select([], [self._master], [], 0.05)
                continue
            if item is None:
                self.finished.set()
                self._stop.wait()
                return
            self._stop.wait(min(0.05, max(0.0, item[0] / self.speed - (time.perf_counter() - t0))))
