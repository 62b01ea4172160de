"""An IMU sample's measurement time on the host clock from its device time (snreg.imu.device_clock), against the
true times of a seeded stream that arrives late in bursts, as a starved reader or sender delivers it."""

import numpy as np

from snreg.imu.device_clock import DeviceClock
from snreg.imu.protocol import DEVICE_CLOCK_WRAP_US

PERIOD_NS = 4_807_692          # 208 Hz


def stream(seed, seconds, *, drift_ppm=0.0, start_us=0, t0_ns=10**12):
    """(measured ns, device us, received ns) per sample: a device clock running ``drift_ppm`` off the host's, from
    ``start_us``; each sample received 0.2-1 ms after it was measured, and now and then (about once a second) the
    reader held back for up to half a second, everything measured meanwhile received at once when it runs again."""
    rng = np.random.default_rng(seed)
    n = int(seconds * 1e9 / PERIOD_NS)
    measured = t0_ns + np.arange(n, dtype=np.int64) * PERIOD_NS
    device = (start_us + np.round((measured - t0_ns) / 1000 * (1 + drift_ppm * 1e-6)).astype(np.int64)) \
        % DEVICE_CLOCK_WRAP_US
    received = measured + rng.integers(200_000, 1_000_000, n)
    for start in rng.choice(n, size=max(1, int(seconds)), replace=False):
        held = rng.integers(20_000_000, 500_000_000)       # the reader starved for this long
        burst = (measured >= measured[start]) & (measured < measured[start] + held)
        received[burst] = np.maximum(received[burst], measured[start] + held)
    return measured, device, np.maximum.accumulate(received)          # a serial line keeps its order


def mapped(device, received, **options):
    clock = DeviceClock(**options)
    return np.array([clock.host_ns(d, r) for d, r in zip(device, received)])


def test_samples_received_late_in_bursts_are_timed_when_they_were_measured():
    measured, device, received = stream(1, 30.0, start_us=DEVICE_CLOCK_WRAP_US - 5_000_000)   # wraps after 5 s
    times = mapped(device, received)
    assert (received - measured).max() > 300e6                        # stamped on arrival: up to half a second late
    settled = measured > measured[0] + 2e9                             # once a sample that waited little was seen
    assert np.abs(times - measured)[settled].max() < 1.0e6             # within the serial latency
    assert (times <= received).all()                                   # never after it arrived


def test_a_device_clock_slower_than_the_host_stays_in_step_over_ten_minutes():
    """A global minimum would stay at the first seconds' offset while 50 ppm accumulate to 30 ms; the window's
    follows."""
    measured, device, received = stream(2, 600.0, drift_ppm=-50.0)
    error = np.abs(mapped(device, received) - measured)
    assert error[measured > measured[0] + 2e9].max() < 1.5e6
    forever = np.abs(mapped(device, received, window_s=1e6) - measured)          # the least offset ever seen
    assert forever[-1] > 20e6


def test_a_restarted_device_is_timed_by_its_new_clock():
    measured, device, received = stream(3, 20.0)
    restart = len(measured) // 2
    device[restart:] = (device[restart:] - device[restart] + 1234) % DEVICE_CLOCK_WRAP_US    # micros() from ~0 again
    times = mapped(device, received)
    after = measured > measured[restart] + 2e9
    assert np.abs(times - measured)[after].max() < 1.0e6
    assert (times <= received).all()


def test_a_recording_replayed_at_half_speed_is_timed_by_its_device_clock_at_that_rate():
    """Its device clock runs half as fast as the host's: read as a sensor's, its samples would fall ever further
    behind (a second in the ten-second window)."""
    measured, device, received = stream(4, 20.0)
    device = (device // 2) % DEVICE_CLOCK_WRAP_US                      # half a device second per host second
    settled = measured > measured[0] + 2e9
    assert np.abs(mapped(device, received, rate=0.5) - measured)[settled].max() < 1.0e6
    assert np.abs(mapped(device, received) - measured)[settled].max() > 0.5e9


def test_a_reader_kept_from_running_for_seconds_keeps_the_offset_it_knew():
    """Three seconds without a sample arriving, then everything measured meanwhile at once, and the sender behind by
    half a second from then on: the samples are still timed when they were measured."""
    measured, device, received = stream(5, 28.0)                       # within the window of the last timely one
    starved = np.flatnonzero(measured >= measured[0] + 10e9)[0]
    received[starved:] = np.maximum(measured[starved:] + 500_000_000, measured[starved] + 3_000_000_000)
    times = mapped(device, received)
    assert np.abs(times - measured)[measured > measured[0] + 2e9].max() < 1.0e6
