"""IMU orientation (snreg.imu.fusion) and the protractor experiment (thesis §5.3, Fig 19).

Simulated LSM6DSOX readings (snreg.demo.imu_simulator, seeded) against their ground truth; the
x-io sample recording against imufusion driven directly.
"""

from pathlib import Path

import imufusion
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.demo.imu_motion import MotionProfile, rotate, still
from snreg.demo.imu_simulator import ImuSimulator, SensorModel
from snreg.imu.fusion import Fusion, fuse_arrays
from snreg.imu.protocol import ImuSample
from snreg.simulation.imu import EXPERIMENT_SENSOR, format_table, measure_yaw_drift, run_protractor_experiment

RATE = 208.0
XIO_CSV = Path(__file__).resolve().parent / "data" / "imu" / "fusion_sensor_data.csv"


def simulate(segments, seed=0, sensor=EXPERIMENT_SENSOR, initial=None):
    """Readings of a simulated sensor following ``segments``: (t_s, gyro_dps, accel_g, bias_dps)."""
    profile = MotionProfile(segments, initial=initial)
    n = int(profile.duration_s * RATE)
    sim = ImuSimulator(profile, rate_hz=RATE, sensor=sensor, seed=seed, n_samples=n)
    r = sim.readings(n)
    return r.t_s, r.gyro_dps, r.accel_g, sim.gyro_bias_dps


def final_euler(segments, **kwargs):
    t, gyro, accel, _ = simulate(segments, **kwargs)
    return fuse_arrays(t, gyro, accel, sample_rate_hz=RATE)[-1]


# --- Euler convention (docs/design.md, Conventions: yaw about z, pitch about y, roll about x, R = Rz Ry Rx) ---

def test_level_at_rest_is_zero_pitch_and_roll():
    yaw, pitch, roll = final_euler([still(6.0)])
    assert abs(pitch) < 0.05 and abs(roll) < 0.05 and abs(yaw) < 0.05


def test_static_tilt_from_gravity_has_the_design_signs():
    initial = Rotation.from_euler("ZYX", [0.0, 15.0, -10.0], degrees=True)
    _, pitch, roll = final_euler([still(6.0)], initial=initial)
    assert pitch == pytest.approx(15.0, abs=0.1) and roll == pytest.approx(-10.0, abs=0.1)


@pytest.mark.parametrize("axis, expected", [((0, 0, 1), (30.0, 0.0, 0.0)),     # about z: yaw
                                            ((0, 1, 0), (0.0, 30.0, 0.0)),     # about y: pitch
                                            ((1, 0, 0), (0.0, 0.0, 30.0))])    # about x: roll
def test_rotation_about_a_sensor_axis_shows_as_its_angle_with_the_right_sign(axis, expected):
    euler = final_euler([still(5.0), rotate(axis, 30.0, 15.0), still(1.0)])
    np.testing.assert_allclose(euler, expected, atol=0.1)


def test_earth_from_sensor_matches_the_euler_angles():
    t, gyro, accel, _ = simulate([still(5.0), rotate((1, 1, 1), 40.0, 20.0), still(1.0)])
    fusion = Fusion(RATE)
    for g, a in zip(gyro, accel):
        euler = fusion.step(g, a, 1.0 / RATE)
    expected = Rotation.from_euler("ZYX", euler, degrees=True).as_matrix()
    np.testing.assert_allclose(fusion.earth_from_sensor, expected, atol=1e-9)
    truth = MotionProfile([still(5.0), rotate((1, 1, 1), 40.0, 20.0), still(1.0)]).orientation(t[-1])
    assert (truth[0].inv() * fusion.rotation).magnitude() < np.radians(0.1)


# --- device time ---

def samples(t_us, gyro_z):
    return [ImuSample(0, int(t) % (1 << 32), np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, g])) for t, g in zip(t_us, gyro_z)]


def run(sample_list):
    fusion = Fusion(100.0, bias_correction=False)
    return [fusion.update(s) for s in sample_list][-1]


def test_integration_uses_device_time_across_the_32_bit_wrap():
    t_us = np.arange(500) * 10_000                      # 100 Hz; 4 s still, then 1 s at 10 deg/s
    gyro_z = np.where(np.arange(500) >= 400, 10.0, 0.0)
    plain = run(samples(t_us, gyro_z))
    wrapped = run(samples(t_us + (1 << 32) - 4_500_000, gyro_z))     # wraps during the turn
    assert plain[0] == pytest.approx(10.0, abs=0.02)
    np.testing.assert_allclose(wrapped, plain, atol=1e-6)
    slow = run(samples(np.arange(500) * 20_000, gyro_z))             # the same samples 20 ms apart: twice the turn
    assert slow[0] == pytest.approx(20.0, abs=0.04)


def test_a_device_restart_integrates_over_the_nominal_period():
    t_us = np.arange(500) * 10_000
    t_us[450:] -= 3_000_000                             # the device clock jumps back mid-turn
    gyro_z = np.where(np.arange(500) >= 400, 10.0, 0.0)
    assert run(samples(t_us, gyro_z))[0] == pytest.approx(10.0, abs=0.02)


# --- flags and states ---

def test_status_reports_startup_rejection_and_overrange():
    fusion = Fusion(100.0)
    level = np.array([0.0, 0.0, 1.0])
    fusion.step(np.zeros(3), level, 0.01)
    assert fusion.status.initialising
    for _ in range(400):
        fusion.step(np.zeros(3), level, 0.01)
    status = fusion.status
    assert not status.initialising and status.bias_calibrated and not status.accelerometer_ignored
    fusion.step(np.zeros(3), np.array([0.0, 0.5, 1.0]), 0.01)          # a jolt: gravity off by 27 deg
    assert fusion.status.accelerometer_ignored
    assert fusion.status.acceleration_error_deg == pytest.approx(26.6, abs=0.1)
    fusion.step(np.array([130.0, 0.0, 0.0]), level, 0.01)              # beyond the 125 deg/s range
    assert fusion.status.angular_rate_recovery


def test_no_initial_bias_estimate_when_moving_at_start():
    t, gyro, accel, _ = simulate([rotate((0, 0, 1), 60.0, 15.0), still(1.0)])
    fusion = Fusion(RATE)
    for g, a in zip(gyro, accel):
        fusion.step(g, a, 1.0 / RATE)
    assert not fusion.status.bias_calibrated


# --- gyro bias and yaw drift ---

@pytest.mark.slow
def test_bias_estimate_converges_to_the_simulated_bias_at_rest():
    t, gyro, accel, bias = simulate([still(60.0)], sensor=SensorModel(gyro_bias_max_dps=0.3), seed=3)
    initial = Fusion(RATE)                              # initial still-period estimate (3 s)
    runtime = Fusion(RATE, initial_bias_period_s=0)     # imufusion's run-time estimate alone
    early = None
    for k, (g, a) in enumerate(zip(gyro, accel)):
        initial.step(g, a, 1.0 / RATE)
        runtime.step(g, a, 1.0 / RATE)
        if k == int(5 * RATE):
            np.testing.assert_allclose(initial.bias_dps, bias, atol=0.01)
            early = np.abs(runtime.bias_dps - bias).max()
    np.testing.assert_allclose(initial.bias_dps, bias, atol=0.01)
    np.testing.assert_allclose(runtime.bias_dps, bias, atol=0.01)
    assert early > 0.05                                 # the run-time estimate needed the minute
    assert np.all(Fusion(RATE, bias_correction=False).bias_dps == 0)


def test_yaw_drift_is_smaller_with_bias_correction():
    corrected = measure_yaw_drift(seed=1, seconds=40.0)
    raw = measure_yaw_drift(seed=1, seconds=40.0, bias_correction=False)
    assert raw.deg_per_min == pytest.approx(60.0 * raw.bias_dps[2], rel=0.05)   # uncorrected: the z bias
    assert abs(corrected.deg_per_min) < 0.2 < abs(raw.deg_per_min) / 10


# --- the protractor experiment (thesis Fig 19) ---

@pytest.mark.parametrize("seed", [0, 1])
def test_protractor_experiment_mean_error_within_0_2_degrees(seed):
    results = run_protractor_experiment(seed)
    assert {(r.rotation, r.angle_deg) for r in results} == {(k, a) for k in ("yaw", "tilt") for a in (1.0, 5.0, 10.0)}
    assert all(len(r.measured_deg) == 4 for r in results)
    assert max(r.mean_error_deg for r in results) <= 0.2, format_table(results)
    table = format_table(results)
    assert table.count("\n") == 8 and "| all |" in table


# --- the x-io sample recording against imufusion driven directly ---

def test_fuse_arrays_equals_imufusion_on_the_xio_recording():
    data = np.genfromtxt(XIO_CSV, delimiter=",", names=True)
    names = data.dtype.names                            # genfromtxt mangles "Gyroscope X (deg/s)" to Gyroscope_X_degs
    t = data[names[0]]
    gyro = np.column_stack([data[n] for n in names[1:4]])
    accel = np.column_stack([data[n] for n in names[4:7]])
    assert names[1].startswith("Gyroscope_X") and names[4].startswith("Accelerometer_X")
    assert np.abs(gyro).max() > 125                     # hence the 2000 deg/s range

    ours = fuse_arrays(t, gyro, accel, gyroscope_range_dps=2000.0, initial_bias_period_s=0)

    rate = 1.0 / np.median(np.diff(t))
    ahrs = imufusion.Ahrs()
    ahrs.set_settings(imufusion.AhrsSettings(sample_rate=rate, convention=imufusion.CONVENTION_NWU, gain=0.5,
                                             gyroscope_range=2000.0, acceleration_rejection=10.0,
                                             magnetic_rejection=0.0, rejection_timeout=5.0))
    bias = imufusion.Bias()
    bias.set_settings(imufusion.BiasSettings(sample_rate=rate, stationary_threshold=0.5, stationary_period=3.0))
    reference = np.empty((len(t), 3))
    for k, dt in enumerate(np.diff(t, prepend=t[0] - 1.0 / rate)):
        ahrs.set_sample_period(dt)
        ahrs.update_no_magnetometer(bias.update(gyro[k]), accel[k])
        roll, pitch, yaw = imufusion.quaternion_to_euler(ahrs.get_quaternion())
        reference[k] = yaw, pitch, roll
    difference = (ours - reference + 180.0) % 360.0 - 180.0
    assert np.abs(difference).max() < 1e-3


def test_fuse_arrays_rejects_mismatched_shapes():
    with pytest.raises(ValueError, match="gyro"):
        fuse_arrays(np.arange(5) / RATE, np.zeros((4, 3)), np.zeros((5, 3)))
