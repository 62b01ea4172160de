"""When an IMU sample was measured, on the host clock: its device time mapped through the offset of the samples that
arrived soonest.

Why: a sample's receive time trails its measurement by the serial latency (a few ms) plus however long the reader
thread or the sender was kept from running. On a loaded computer (five processes on two cores) samples arrive in
bursts up to half a second late, all stamped with the burst's receive time, and a frame paired with them by host
time got the orientation of up to half a second before: 2-6 degrees off during a turn. The device clock
(``t_device_us``, Arduino ``micros()``) ticks when each sample is measured, so ``device time + offset`` is the
measurement's host time, the offset being the smallest ``receive - device`` seen (the samples that waited least,
whose delay is the latency alone). The minimum is taken over the last :data:`WINDOW_S` seconds, so the two clocks'
drift (tens of ppm: a few ms a minute) never accumulates, and it starts again when the device's clock jumps (a restart,
or a reconnect after a while). A pause in what arrives while the device's clock runs on is no reason: a reader or
sender kept from running for seconds (load 30 on 2 cores) delivers nothing but late samples afterwards, and starting
again from them would take their lateness for the offset. A stream whose device clock runs faster or slower than the host's by
design (a recording replayed ``speed`` times faster) says so with ``rate``. A mapped time is never later than its own receive time, and never earlier
than the one before.
"""

from __future__ import annotations

from collections import deque

from snreg.imu.protocol import DEVICE_CLOCK_WRAP_US, RESTART_GAP_US

__all__ = ["DeviceClock", "WINDOW_S"]

WINDOW_S = 20.0     # the offset is the least over this many seconds of samples (drift: about a millisecond)


class DeviceClock:
    """Maps each sample's device time (us, wrapping at 2^32) to the host clock (ns), in arrival order; ``rate``: device
    seconds per host second (1 for a sensor; a replay's speed)."""

    def __init__(self, window_s: float = WINDOW_S, *, rate: float = 1.0):
        if not rate > 0:
            raise ValueError(f"the device clock's rate must be a positive number, got {rate}")
        self._window_ns, self._rate = int(window_s * 1e9), float(rate)
        self._offsets: deque[tuple[int, int]] = deque()   # (receive ns, receive - device ns), increasing offsets
        self._last_us: int | None = None
        self._device_ns = 0                                # the device time unwrapped, in host ns
        self._last_ns = -(1 << 62)                         # the last time given: times never go backwards

    def host_ns(self, t_device_us: int, receive_ns: int) -> int:
        """The host time (ns) the sample with device time ``t_device_us`` was measured at, given when it arrived."""
        t_device_us, receive_ns = int(t_device_us), int(receive_ns)
        step = None if self._last_us is None else (t_device_us - self._last_us) % DEVICE_CLOCK_WRAP_US
        if step is None or step > RESTART_GAP_US:
            self._offsets.clear()                          # the first sample, or the device's clock jumped
            self._device_ns = round(t_device_us * 1000 / self._rate)
        else:
            self._device_ns += round(step * 1000 / self._rate)
        self._last_us = t_device_us
        offset = receive_ns - self._device_ns
        while self._offsets and self._offsets[-1][1] >= offset:      # a sliding minimum: increasing offsets kept
            self._offsets.pop()
        self._offsets.append((receive_ns, offset))
        while self._offsets[0][0] < receive_ns - self._window_ns:
            self._offsets.popleft()
        # in order, also when a sample that waited less than all before lowers the offset
        self._last_ns = max(self._device_ns + self._offsets[0][1], self._last_ns + 1)
        return self._last_ns
