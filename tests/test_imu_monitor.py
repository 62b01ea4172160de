"""The IMU orientation at a frame's grab time (snreg.imu.monitor.interpolate_orientation), not the latest one."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.geometry import euler_from_rotation
from snreg.imu.monitor import ImuAt, interpolate_orientation


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
