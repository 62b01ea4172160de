"""The IMU orientation at a frame's grab time (snreg.imu.monitor.interpolate_orientation), not the latest one; the
monitor that keeps it from the serial stream."""

import os
import threading
import time
import tty

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from conftest import poll

from snreg.geometry import euler_from_rotation
from snreg.imu.device_clock import DeviceClock
from snreg.imu.fusion import Fusion
from snreg.imu.monitor import ImuAt, ImuMonitor, interpolate_orientation
from snreg.imu.protocol import format_line, parse_line


def _history(yaws_deg, t0_ns=10**12, step_ns=4_807_692):
    times = t0_ns + step_ns * np.arange(len(yaws_deg), dtype=np.int64)
    quats = Rotation.from_euler("ZYX", [[yaw, 0.0, 0.0] for yaw in yaws_deg], degrees=True).as_quat()
    return times, quats


def test_between_samples_the_orientation_is_slerped_at_the_frame_time():
    times, quats = _history([0.0, 10.0, 30.0])
    t = times[1] + (times[2] - times[1]) // 4                     # a quarter of the way from 10 to 30 degrees
    earth_from_imu, gap_s = interpolate_orientation(times, quats, int(t))
    assert euler_from_rotation(earth_from_imu)[0] == pytest.approx(15.0, abs=1e-3)
    assert gap_s == pytest.approx((t - times[1]) / 1e9)



def test_the_interpolation_is_scipys_slerp_to_the_last_bit():
    """Slerp done step by step (issue 36: building a Slerp object per pair cost the worker) gives the very
    orientation scipy's Slerp gives, between turns of any size, at any time between two samples (seeded)."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        times = np.sort(rng.integers(10**12, 10**12 + 10**8, 2)) + np.array([0, 1])
        quats = Rotation.random(2, random_state=rng).as_quat()
        t = int(rng.integers(times[0] + 1, times[1] + 1))
        expected = Slerp(times.astype(float), Rotation.from_quat(quats))([float(t)])[0].as_matrix()
        assert np.array_equal(interpolate_orientation(times, quats, t)[0], expected)

def test_outside_the_samples_the_nearest_is_used_and_the_gap_says_how_far():
    times, quats = _history([0.0, 10.0, 20.0])
    later, gap_s = interpolate_orientation(times, quats, int(times[-1]) + 2_500_000_000)
    assert euler_from_rotation(later)[0] == pytest.approx(20.0, abs=1e-6) and gap_s == pytest.approx(2.5)
    assert ImuAt(later, gap_s, "disconnected").stale
    earlier, gap_s = interpolate_orientation(times, quats, int(times[0]) - 1_000_000)
    assert euler_from_rotation(earlier)[0] == pytest.approx(0.0, abs=1e-6) and gap_s == pytest.approx(0.001)
    none, gap_s = interpolate_orientation(np.zeros(0, np.int64), np.zeros((0, 4)), 5)
    np.testing.assert_array_equal(none, np.eye(3))
    assert gap_s == float("inf")


def _burst(first_us, n, rate_dps=30.0, step_us=4808):
    """``n`` sample lines of a sensor rolled 30 degrees and rolling on at ``rate_dps`` (its orientation moves from one
    sample to the next, also while imufusion holds the heading at start), device times from ``first_us``."""
    return [format_line(first_us + k * step_us, [0.0, 0.5, 0.866], [rate_dps, 0.0, 0.0]) for k in range(n)]


def sent_after(burst) -> bool:
    """The six samples after ``burst`` have been measured by now: a device sends no sample before its time."""
    return time.perf_counter_ns() > burst[-1].t_host_ns + 6 * 4_808_000


def test_the_monitor_keeps_each_sample_fused_and_answers_with_the_orientation_at_a_time():
    """Two bursts on a pty: the latest orientation is the fusion's after the last sample, the orientation at a time
    between two samples is slerped between them, each sample timed when it was measured (its device time mapped
    through the soonest arrival: the second burst, written later, follows the first by its device times, not by when
    it arrived), and every raw sample is handed on for recording."""
    lines = _burst(1000, 6) + _burst(1000 + 6 * 4808, 6)
    offline = Fusion(208.0)
    quats = []
    for sample in (parse_line(line) for line in lines):
        offline.advance(sample)
        quats.append(offline.rotation.as_quat())
    master, slave = os.openpty()
    tty.setraw(slave)
    monitor = ImuMonitor(os.ttyname(slave))
    try:
        monitor.start()
        assert poll(lambda: monitor.snapshot().state == "connecting")
        os.write(master, b"".join(lines[:6]))
        assert poll(lambda: monitor.snapshot().samples == 6)
        first = monitor.take_samples()
        assert poll(lambda: sent_after(first))         # as a device sends them: not before it measured them
        os.write(master, b"".join(lines[6:]))
        assert poll(lambda: monitor.snapshot().samples == 12)
        second = monitor.take_samples()
        snapshot = monitor.snapshot()
        clock = DeviceClock()
        measured = [clock.host_ns(s.t_device_us, s.t_host_ns) for s in first + second]
        between = (measured[5] + measured[6]) // 2
        at = monitor.orientation_at(between)
    finally:
        monitor.stop()
        os.close(master)
        os.close(slave)
    after = monitor.orientation_at(measured[-1] + 500_000_000)        # stopped: answered at once
    assert [s.t_device_us for s in first + second] == [parse_line(line).t_device_us for line in lines]
    np.testing.assert_allclose(snapshot.earth_from_imu, Rotation.from_quat(quats[-1]).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(snapshot.euler_deg, offline.euler, atol=1e-9)
    assert abs(snapshot.euler_deg[2]) > 0.1
    assert snapshot.rate_hz == 12.0                 # samples received within the last second
    np.testing.assert_allclose(after.earth_from_imu, snapshot.earth_from_imu, atol=1e-12)
    assert after.gap_s == pytest.approx(0.5)
    assert measured[6] - measured[5] == pytest.approx(4_808_000, abs=100)               # by device time,
    assert second[0].t_host_ns - first[-1].t_host_ns > 6 * 4_808_000                    # not by arrival
    expected, _ = interpolate_orientation(np.array(measured[5:7]), np.array([quats[5], quats[6]]), between)
    np.testing.assert_allclose(at.earth_from_imu, expected, atol=1e-12)
    assert not np.allclose(at.earth_from_imu, after.earth_from_imu, atol=1e-6)


def test_a_time_the_samples_have_not_reached_is_waited_for_while_the_imu_streams():
    """A frame grabbed before its IMU samples arrived (a sender or reader running late) gets the orientation at its
    own time once they do, not the last one received; a stopped IMU is not waited for."""
    lines = _burst(1000, 6) + _burst(1000 + 6 * 4808, 6)
    master, slave = os.openpty()
    tty.setraw(slave)
    monitor = ImuMonitor(os.ttyname(slave), wait_s=30.0)
    answers = []
    try:
        monitor.start()
        assert poll(lambda: monitor.snapshot().state == "connecting")
        os.write(master, b"".join(lines[:6]))
        assert poll(lambda: monitor.snapshot().samples == 6)
        first = monitor.take_samples()
        clock = DeviceClock()
        last = [clock.host_ns(s.t_device_us, s.t_host_ns) for s in first][-1]
        frame_ns = last + 3 * 4_808_000 // 2                         # between samples 7 and 8: not sent yet
        asking = threading.Thread(target=lambda: answers.append(monitor.orientation_at(frame_ns)))
        asking.start()
        assert poll(lambda: monitor.waiting == 1 and sent_after(first))
        os.write(master, b"".join(lines[6:]))
        asking.join(30)
        assert poll(lambda: monitor.snapshot().samples == 12)
        latest = monitor.snapshot().earth_from_imu
    finally:
        monitor.stop()
        os.close(master)
        os.close(slave)
    assert answers and answers[0].gap_s == pytest.approx(4_808_000 / 2e9, abs=1e-6)    # between two samples
    assert not np.allclose(answers[0].earth_from_imu, latest, atol=1e-6)
    started = time.monotonic()
    stopped = monitor.orientation_at(frame_ns + 10**9)
    assert time.monotonic() - started < 5.0 and stopped.gap_s > 0.9
