"""Read the IMU's serial stream in a thread (pyserial), with host time stamps, counts and states.

:class:`SerialImuReader` opens a port by name (a real ``/dev/ttyACM0``/``COM3`` or a simulator's
pseudo-terminal), decodes the line protocol (:mod:`snreg.imu.protocol`), stamps each chunk it
reads with ``time.perf_counter_ns()`` next to the device time, and hands samples to a callback
and/or a bounded queue. It reports its state (connecting, streaming, stale, disconnected,
stopped) with a one-sentence ``problem``, and reconnects by itself when an unplugged port comes
back. Garbage on the line is counted, never raised.
"""

from __future__ import annotations

import enum
import logging
import queue
import threading
import time
from collections.abc import Callable

import serial

from snreg.errors import ImuPortError
from snreg.imu.protocol import CorruptLine, ImuSample, InfoLine, StreamCounts, StreamDecoder

__all__ = ["SerialImuReader", "ImuState", "ImuPortError", "DEFAULT_BAUD"]

DEFAULT_BAUD = 230400        # the firmware's rate: 208 lines/s of ~80 bytes need > 115200 baud
_log = logging.getLogger(__name__)


class ImuState(enum.Enum):
    CONNECTING = "connecting"       # port open (or being opened), no valid sample yet
    STREAMING = "streaming"         # valid samples arriving
    STALE = "stale"                 # port open but no valid sample for ``stale_after_s``
    DISCONNECTED = "disconnected"   # the port vanished (unplugged); retrying
    STOPPED = "stopped"             # stop() was called


class SerialImuReader:
    """The IMU stream from one serial port, read in its own thread.

    on_sample(sample): called in the reader thread for every valid sample; keep it short. An
        exception from it is logged and the stream goes on.
    on_state(state, problem): called in the reader thread on every state change.
    queue_size: if given, samples also go to ``self.queue`` (a ``queue.Queue`` of that size); when it
        is full the sample is not queued and ``overflow`` counts it.
    rate_hz: nominal rate for drop detection; None: the rate the device announces, else 208 Hz.
    stale_after_s: silence (no valid sample) after which the state is STALE.
    retry_interval_s: time between attempts to reopen a vanished port.
    read_timeout_s: longest a read blocks; bounds the reaction time to stop() and staleness.
    """

    def __init__(self, port: str, baudrate: int = DEFAULT_BAUD, *, on_sample: Callable[[ImuSample], None] | None = None,
                 on_state: Callable[[ImuState, str], None] | None = None, queue_size: int | None = None,
                 rate_hz: float | None = None, stale_after_s: float = 0.5, retry_interval_s: float = 1.0,
                 read_timeout_s: float = 0.05):
        if not (stale_after_s > 0 and retry_interval_s > 0 and read_timeout_s > 0):
            raise ValueError("stale_after_s, retry_interval_s and read_timeout_s must be positive")
        self.port, self.baudrate = str(port), int(baudrate)
        self.on_sample, self.on_state = on_sample, on_state
        self.queue: queue.Queue | None = queue.Queue(queue_size) if queue_size else None
        self.overflow = 0
        self.stale_after_s, self.retry_interval_s, self.read_timeout_s = stale_after_s, retry_interval_s, read_timeout_s
        self._decoder = StreamDecoder(rate_hz)
        self._serial: serial.Serial | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._state, self._problem = ImuState.STOPPED, ""
        self._last_valid_ns = 0

    @property
    def state(self) -> ImuState:
        return self._state

    @property
    def problem(self) -> str:
        """Why the state is not STREAMING, in one sentence ("" while streaming)."""
        return self._problem

    @property
    def counts(self) -> StreamCounts:
        """Samples, corrupt lines and dropped samples since start (a consistent snapshot)."""
        return self._decoder.counts

    @property
    def last_corrupt(self) -> CorruptLine | None:
        """The last line that failed, with the reason: what to look at when ``corrupt`` grows."""
        return self._decoder.last_corrupt

    @property
    def info(self) -> InfoLine | None:
        """The device's last ``#`` line that announced its rate, if any."""
        return self._decoder.info

    @property
    def rate_hz(self) -> float:
        """The nominal sample rate in use (Hz)."""
        return self._decoder.rate_hz

    def start(self) -> SerialImuReader:
        """Open the port (ImuPortError if that fails) and start the reader thread."""
        if self._thread is not None:
            raise RuntimeError("this reader was already started")
        try:
            self._serial = self._open()
        except (serial.SerialException, OSError, ValueError) as err:
            raise ImuPortError(_open_advice(self.port, err)) from None
        self._set_state(ImuState.CONNECTING, f"waiting for the first IMU sample on {self.port}")
        self._thread = threading.Thread(target=self._run, name=f"imu-reader {self.port}", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """Stop reading, close the port and join the thread."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def __enter__(self) -> SerialImuReader:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _open(self) -> serial.Serial:
        self._last_valid_ns = time.perf_counter_ns()
        self._decoder.resync()
        return serial.Serial(self.port, self.baudrate, timeout=self.read_timeout_s)

    def _set_state(self, state: ImuState, problem: str = "") -> None:
        self._problem = problem
        if state is not self._state:
            self._state = state
            if self.on_state is not None:
                try:
                    self.on_state(state, problem)
                except Exception:
                    _log.exception("IMU on_state callback failed; the stream goes on")

    def _run(self) -> None:
        while not self._stop.is_set():
            if self._serial is None:
                self._reconnect()
                continue
            try:
                data = self._read()
            except (serial.SerialException, OSError) as err:
                self._close()
                if self._state is not ImuState.DISCONNECTED:      # the port's own words go to the log: they guess
                    _log.warning("IMU port %s: %s", self.port, err)     # ("multiple access on port?") where we know
                self._set_state(ImuState.DISCONNECTED, f"the IMU port {self.port} went away; reconnect the sensor, "
                                f"retrying every {self.retry_interval_s:g} s")
                continue
            now = time.perf_counter_ns()
            if data:
                self._deliver(data, now)
            if self._state is not ImuState.STALE and now - self._last_valid_ns > self.stale_after_s * 1e9:
                self._set_state(ImuState.STALE, f"no valid IMU sample for {self.stale_after_s:g} s on {self.port}; "
                                "check the sensor, its cable and the baud rate")
        self._close()
        self._set_state(ImuState.STOPPED)

    def _read(self) -> bytes:
        """What the port holds, waiting (at most ``read_timeout_s``) for its first byte: a line that arrives at once,
        as a device sends it, is read in one wake-up of this thread, not its first byte apart from the rest."""
        data = self._serial.read(1)
        waiting = self._serial.in_waiting if data else 0
        return data + self._serial.read(waiting) if waiting else data

    def _reconnect(self) -> None:
        if self._stop.wait(self.retry_interval_s):
            return
        try:
            self._serial = self._open()
        except (serial.SerialException, OSError, ValueError):
            return
        self._set_state(ImuState.CONNECTING, f"reconnected to {self.port}, waiting for the first IMU sample")

    def _deliver(self, data: bytes, t_host_ns: int) -> None:
        samples = [item for item in self._decoder.feed(data, t_host_ns) if isinstance(item, ImuSample)]
        if samples:
            self._last_valid_ns = t_host_ns
            self._set_state(ImuState.STREAMING)
        for item in samples:
            if self.queue is not None:
                try:
                    self.queue.put_nowait(item)
                except queue.Full:
                    self.overflow += 1
            if self.on_sample is not None:
                try:
                    self.on_sample(item)
                except Exception:
                    _log.exception("IMU on_sample callback failed; the stream goes on")

    def _close(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            except (serial.SerialException, OSError):
                pass
            self._serial = None


def _open_advice(port: str, err: Exception) -> str:
    hint = ("add your user to the 'dialout' group and log in again" if getattr(err, "errno", None) == 13
            else "check that the IMU is plugged in, that the port name is right (e.g. /dev/ttyACM0 or COM3) "
                 "and that no other program, such as the Arduino serial monitor, holds it")
    return f"Cannot open the IMU port {port} ({err}); {hint}."
