"""The IMU serial line protocol (docs/design.md, Contracts "IMU serial protocol") and its stream decoder.

A sample line is ``$IMU,<t_us>,<ax>,<ay>,<az>,<gx>,<gy>,<gz>*<CS>``: device time in
microseconds (Arduino ``micros()``, unsigned 32 bit, wraps after 71.6 min), acceleration in
g, angular rate in deg/s, and ``CS``, two hex digits: the XOR of the bytes between ``$`` and
``*``. Lines starting with ``#`` are information (``# snreg-imu 1 LSM6DSOX odr_hz=208``).
Lines end in ``\\r\\n`` (Arduino ``println``); surrounding whitespace is ignored.

:func:`parse_line` never raises: a line that is not a valid sample or information line comes
back as a :class:`CorruptLine` with the reason, so a reader can count it and go on.
:class:`StreamDecoder` turns raw bytes into samples and keeps the counts a reader reports.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

__all__ = ["ImuSample", "InfoLine", "CorruptLine", "StreamCounts", "StreamDecoder", "checksum", "format_line",
           "format_info", "parse_line", "DEFAULT_ODR_HZ", "DEVICE_CLOCK_WRAP_US", "MAX_LINE_BYTES"]

PROTOCOL_VERSION = 1
DEFAULT_ODR_HZ = 208.0             # LSM6DSOX output data rate in the thesis set-up (thesis §2.4)
DEVICE_CLOCK_WRAP_US = 1 << 32     # micros() is an unsigned 32-bit counter
MAX_LINE_BYTES = 256               # longer lines are garbage (a valid sample line is ~80 bytes)
RESTART_GAP_US = 1_000_000         # a device-time step beyond 1 s (or backwards) is a restart, not lost samples

_NUMBER = rb"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_FRAME = re.compile(rb"\$([^*]*)\*([0-9A-Fa-f]{2})")
_BODY = re.compile(rb"IMU,(\d{1,10})" + rb"".join(rb",(" + _NUMBER + rb")" for _ in range(6)))
_ODR = re.compile(r"(?:^|\s)odr_hz=(\d+(?:\.\d*)?)(?:\s|$)")


@dataclass(frozen=True, eq=False)
class ImuSample:
    """One reading: host receive time (``time.perf_counter_ns()``), device time (us, mod 2**32),
    acceleration (3,) in g and angular rate (3,) in deg/s, both in the sensor frame (read-only arrays)."""

    t_host_ns: int
    t_device_us: int
    accel_g: np.ndarray
    gyro_dps: np.ndarray

    def __post_init__(self):
        for name in ("accel_g", "gyro_dps"):
            value = np.array(getattr(self, name), dtype=float).reshape(3)
            value.setflags(write=False)
            object.__setattr__(self, name, value)


@dataclass(frozen=True)
class InfoLine:
    """A ``#`` line, its text without the ``#``; ``odr_hz`` is the announced output data rate, if any."""

    text: str

    @property
    def odr_hz(self) -> float | None:
        match = _ODR.search(self.text)
        rate = float(match.group(1)) if match else 0.0
        return rate if rate > 0 else None


@dataclass(frozen=True)
class CorruptLine:
    """A line that failed: the raw bytes and why (a short phrase, e.g. "checksum mismatch")."""

    raw: bytes
    reason: str


@dataclass(frozen=True)
class StreamCounts:
    """samples: valid sample lines; corrupt: lines that failed checksum or parsing; dropped: samples
    missing from the device-time sequence (gaps longer than 1.5 nominal periods, in periods)."""

    samples: int = 0
    corrupt: int = 0
    dropped: int = 0


def checksum(body: bytes) -> int:
    """XOR of ``body``'s bytes: the protocol checksum of the text between ``$`` and ``*``."""
    value = 0
    for byte in body:
        value ^= byte
    return value


def format_line(t_device_us: int, accel_g, gyro_dps, decimals: int = 6) -> bytes:
    """One sample line with CRLF; values printed fixed-point with ``decimals`` digits.

    Six decimals print the LSM6DSOX's LSBs exactly (0.122 mg at +-4 g, 4.375 mdps at +-125 dps).
    Raises ValueError for a time outside 0..2**32-1 or a non-finite value: the protocol cannot carry them.
    """
    values = [float(v) for v in (*np.asarray(accel_g, dtype=float).reshape(3), *np.asarray(gyro_dps, dtype=float).reshape(3))]
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"IMU values must be finite, got {values}")
    if not 0 <= int(t_device_us) < DEVICE_CLOCK_WRAP_US:
        raise ValueError(f"device time must be in 0..2**32-1 us, got {t_device_us}")
    body = f"IMU,{int(t_device_us)}," + ",".join(f"{v:.{decimals}f}" for v in values)
    raw = body.encode("ascii")
    return b"$" + raw + b"*%02X\r\n" % checksum(raw)


def format_info(odr_hz: float, sensor: str = "LSM6DSOX", extra: str = "") -> bytes:
    """The information line a device prints at start: ``# snreg-imu 1 <sensor> odr_hz=<rate> [extra]``."""
    text = f"# snreg-imu {PROTOCOL_VERSION} {sensor} odr_hz={odr_hz:g}"
    return (text + (f" {extra}" if extra else "") + "\r\n").encode("utf-8")


def parse_line(line: bytes, t_host_ns: int = 0) -> ImuSample | InfoLine | CorruptLine | None:
    """Parse one line (with or without its line ending); never raises.

    Returns an :class:`ImuSample` stamped with ``t_host_ns``, an :class:`InfoLine`, ``None`` for a
    blank line, or a :class:`CorruptLine` for anything else: bad checksum, truncated, binary,
    non-numeric or non-finite values, wrong field count, device time beyond 32 bits, non-UTF-8.
    """
    line = bytes(line).strip()
    if not line:
        return None
    if len(line) > MAX_LINE_BYTES:
        return CorruptLine(line, f"longer than {MAX_LINE_BYTES} bytes")
    if line.startswith(b"#"):
        try:
            return InfoLine(line[1:].decode("utf-8").strip())
        except UnicodeDecodeError:
            return CorruptLine(line, "information line is not UTF-8")
    frame = _FRAME.fullmatch(line)
    if frame is None:
        reason = "no $...*checksum frame (truncated?)" if line.startswith(b"$") else "not a protocol line"
        return CorruptLine(line, reason)
    body, sent = frame.group(1), int(frame.group(2), 16)
    if checksum(body) != sent:
        return CorruptLine(line, "checksum mismatch")
    fields = _BODY.fullmatch(body)
    if fields is None:
        return CorruptLine(line, "not $IMU with a time and six numbers")
    t_us = int(fields.group(1))
    values = [float(v) for v in fields.groups()[1:]]
    if t_us >= DEVICE_CLOCK_WRAP_US:
        return CorruptLine(line, "device time beyond 32 bits")
    if not all(math.isfinite(v) for v in values):
        return CorruptLine(line, "non-finite value")
    return ImuSample(int(t_host_ns), t_us, np.array(values[:3]), np.array(values[3:]))


class StreamDecoder:
    """Bytes in, samples out: splits lines, parses them and keeps :class:`StreamCounts`.

    rate_hz: nominal sample rate for gap detection; ``None`` takes the rate a ``#`` line announces
        (``odr_hz=``), else 208 Hz; a ``#`` line without a rate (perhaps a sample whose ``$`` was corrupted
        to ``#``) leaves it as it was. A step in device time (mod 2**32, so the micros() wrap is no gap)
        longer than 1.5 periods counts ``round(step / period) - 1`` dropped samples; a step back or
        beyond 1 s is a device restart and counts nothing. Lines longer than 256 bytes count as one
        corrupt line each. Not thread-safe: one decoder per reader thread.
    """

    def __init__(self, rate_hz: float | None = None):
        if rate_hz is not None and not rate_hz > 0:
            raise ValueError(f"IMU sample rate must be positive, got {rate_hz} Hz")
        self._rate_hz = rate_hz
        self.info: InfoLine | None = None       # the last ``#`` line that announced a rate
        self.last_corrupt: CorruptLine | None = None
        self.counts = StreamCounts()
        self._partial = b""
        self._skipping = False       # inside an over-long line already counted corrupt
        self._last_us: int | None = None

    @property
    def rate_hz(self) -> float:
        """The nominal rate in use (Hz)."""
        announced = self.info.odr_hz if self.info else None
        return self._rate_hz or announced or DEFAULT_ODR_HZ

    def resync(self) -> None:
        """Forget the partial line and the last device time (after a reconnect: a gap there is no drop)."""
        self._partial, self._skipping, self._last_us = b"", False, None

    def feed(self, data: bytes, t_host_ns: int) -> list[ImuSample | InfoLine]:
        """Decode ``data`` (any chunking); returns the complete samples and info lines in it, in order."""
        *lines, rest = (self._partial + data).split(b"\n")
        out = []
        for line in lines:
            if self._skipping:
                self._skipping = False
                continue
            item = parse_line(line, t_host_ns)
            if isinstance(item, ImuSample):
                self._count_gap(item.t_device_us)
                out.append(item)
            elif isinstance(item, InfoLine):
                if item.odr_hz is not None:      # only a line stating the rate sets it (a corrupted "$" can read "#")
                    self.info = item
                out.append(item)
            elif isinstance(item, CorruptLine):
                self._corrupt(item)
        if len(rest) > MAX_LINE_BYTES:
            if not self._skipping:
                self._corrupt(CorruptLine(rest[:MAX_LINE_BYTES], f"longer than {MAX_LINE_BYTES} bytes"))
            self._skipping, rest = True, b""
        self._partial = rest
        return out

    def _corrupt(self, item: CorruptLine) -> None:
        self.last_corrupt = item
        c = self.counts
        self.counts = StreamCounts(c.samples, c.corrupt + 1, c.dropped)

    def _count_gap(self, t_us: int) -> None:
        missing = 0
        if self._last_us is not None:
            step = (t_us - self._last_us) % DEVICE_CLOCK_WRAP_US
            period = 1e6 / self.rate_hz
            if 1.5 * period < step <= RESTART_GAP_US:
                missing = int(round(step / period)) - 1
        self._last_us = t_us
        c = self.counts
        self.counts = StreamCounts(c.samples + 1, c.corrupt, c.dropped + missing)
