"""The IMU accuracy experiment (thesis §5.3, Fig 19) and the yaw drift, on the simulated LSM6DSOX.

The thesis put the sensor on an adjustable protractor and turned it by 1, 5 and 10 degrees,
4 times each, (a) lying horizontally, turning in the horizontal plane, i.e. about the
vertical axis, which only the gyro sees (yaw; Fig 19B "In XY-plane"), and (b) standing
vertically, turning about a horizontal axis, which gravity also observes (tilt: pitch and
roll; Fig 19B "Around z-axis"). Each measurement is the rotation distance (thesis eq. 5)
between the orientations built from the median yaw, pitch and roll over the still periods
before and after the turn; error = |measured - protractor angle|. Thesis: 0.6 +- 0.15 deg.

Here the motion is known exactly, so the error is the filter's and the sensor's alone (no
protractor reading error, no misalignment, no gyro scale-factor error). The whole experiment
is one recording of one sensor (one gyro bias) from :mod:`snreg.demo.imu_simulator`, fused sample by
sample through :meth:`Fusion.update` on device timestamps that cross the 32-bit wrap:
``initial_still_s`` at rest (imufusion's 3 s startup and the initial bias estimate), then per
rotation type, angle and repeat: hold ``hold_s``, turn at ``rate_dps`` on average (raised-cosine
rate, like a hand), hold ``hold_s``. Successive turns alternate in sign, so the sensor returns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.demo.imu_motion import MotionProfile, rotate, still
from snreg.demo.imu_simulator import ImuSimulator, SensorModel
from snreg.geometry import rotation_distance_deg, rotation_from_euler
from snreg.imu.fusion import Fusion

__all__ = ["CaseResult", "fuse_simulation", "run_protractor_experiment", "format_table", "YawDrift", "measure_yaw_drift",
           "EXPERIMENT_SENSOR", "THESIS_FIG19"]

# The noisy end of the LSM6DSOX datasheet (gyro 3.8-7 mdps/sqrt(Hz), accelerometer 70-100 ug/sqrt(Hz))
# and a constant gyro bias up to 0.3 deg/s per axis; quantised at +-4 g and +-125 deg/s.
EXPERIMENT_SENSOR = SensorModel(accel_noise_density_g=100e-6, gyro_noise_density_dps=7e-3, gyro_bias_max_dps=0.3,
                                accel_range_g=4, gyro_range_dps=125)
ROTATION_AXES = {"yaw": (0.0, 0.0, 1.0),
                 # a horizontal axis 30 deg from x, so the tilt shows in both pitch and roll
                 "tilt": (float(np.cos(np.radians(30.0))), float(np.sin(np.radians(30.0))), 0.0)}
ROTATION_LABELS = {"yaw": "horizontal plane (yaw)", "tilt": "about a horizontal axis (tilt)"}
# thesis Fig 19B: mean (std) error in degrees per rotation type and protractor angle
THESIS_FIG19 = {("yaw", 1.0): (0.3839, 0.0981), ("yaw", 5.0): (0.5932, 0.1101), ("yaw", 10.0): (0.4625, 0.1167),
                ("tilt", 1.0): (0.4162, 0.1458), ("tilt", 5.0): (0.2623, 0.2055), ("tilt", 10.0): (0.5594, 0.1429)}
RATE_HZ = 208.0
_START_US = (1 << 32) - 10_000_000      # the device clock wraps 10 s into every recording


@dataclass(frozen=True)
class CaseResult:
    """One rotation type ("yaw" or "tilt") at one protractor angle: the measured turns (repeats,), degrees."""

    rotation: str
    angle_deg: float
    measured_deg: np.ndarray

    @property
    def errors_deg(self) -> np.ndarray:
        return np.abs(self.measured_deg - self.angle_deg)

    @property
    def mean_error_deg(self) -> float:
        return float(self.errors_deg.mean())

    @property
    def std_error_deg(self) -> float:
        return float(self.errors_deg.std(ddof=1))


def fuse_simulation(simulator: ImuSimulator, n_samples: int, **fusion_settings) -> np.ndarray:
    """(n_samples, 3) yaw, pitch, roll (degrees) from the simulator's readings, sample by sample on the device clock."""
    readings = simulator.readings(n_samples)
    fusion = Fusion(simulator.rate_hz, gyroscope_range_dps=float(simulator.sensor.gyro_range_dps or 0),
                    **fusion_settings)
    return fusion.update_block(readings.t_device_us, readings.accel_g, readings.gyro_dps)


def run_protractor_experiment(seed: int = 0, *, angles=(1.0, 5.0, 10.0), repeats: int = 4,
                              sensor: SensorModel = EXPERIMENT_SENSOR, initial_still_s: float = 5.0,
                              hold_s: float = 2.0, rate_dps: float = 10.0, **fusion_settings) -> list[CaseResult]:
    """Thesis Fig 19 on a simulated sensor: one :class:`CaseResult` per rotation type and angle.

    ``fusion_settings`` go to :class:`~snreg.imu.fusion.Fusion` (the gyro range is the sensor's).
    """
    segments, windows, t = [still(initial_still_s)], [], initial_still_s
    for rotation, axis in ROTATION_AXES.items():
        for angle in angles:
            for k in range(repeats):
                turn = rotate(axis, (-1) ** k * angle, rate_dps)
                segments += [still(hold_s), turn, still(hold_s)]
                windows.append((rotation, angle, (t, t + hold_s), (t + hold_s + turn.duration_s, t + 2 * hold_s + turn.duration_s)))
                t += 2 * hold_s + turn.duration_s
    n = int(np.floor(t * RATE_HZ))
    simulator = ImuSimulator(MotionProfile(segments), rate_hz=RATE_HZ, sensor=sensor, seed=seed, n_samples=n, start_us=_START_US)
    euler = fuse_simulation(simulator, n, **fusion_settings)
    times = np.arange(n) / RATE_HZ

    def median_orientation(span):
        inside = (times >= span[0]) & (times < span[1])
        return rotation_from_euler(*np.median(euler[inside], axis=0))

    measured = {}
    for rotation, angle, before, after in windows:
        distance = float(rotation_distance_deg(median_orientation(before), median_orientation(after)))
        measured.setdefault((rotation, float(angle)), []).append(distance)
    return [CaseResult(rotation, angle, np.array(values)) for (rotation, angle), values in measured.items()]


def format_table(results: list[CaseResult]) -> str:
    """Markdown table: per case the measured turns, error mean +- std, and thesis Fig 19B; then all cases."""
    lines = ["| rotation | protractor (deg) | measured (deg) | error mean ± std (deg) | thesis Fig 19B (deg) |",
             "|---|---|---|---|---|"]
    for r in results:
        thesis = THESIS_FIG19.get((r.rotation, r.angle_deg))
        lines.append(f"| {ROTATION_LABELS[r.rotation]} | {r.angle_deg:g} | {' '.join(f'{m:.3f}' for m in r.measured_deg)} | "
                     f"{r.mean_error_deg:.3f} ± {r.std_error_deg:.3f} | "
                     f"{'' if thesis is None else f'{thesis[0]:.3f} ± {thesis[1]:.3f}'} |")
    errors = np.concatenate([r.errors_deg for r in results])
    lines.append(f"| all | | | {errors.mean():.3f} ± {errors.std(ddof=1):.3f} | 0.6 ± 0.15 |")
    return "\n".join(lines)


@dataclass(frozen=True)
class YawDrift:
    """Yaw drift of a sensor at rest: its simulated gyro bias (3,) deg/s and the drift in deg/min."""

    bias_dps: np.ndarray
    deg_per_min: float


def measure_yaw_drift(seed: int = 0, seconds: float = 120.0, sensor: SensorModel = EXPERIMENT_SENSOR,
                      **fusion_settings) -> YawDrift:
    """Yaw drift of a level sensor at rest: the slope of a line through the yaw after the first 5 s
    (imufusion's startup holds the heading at 0 for 3 s). Uncorrected, it is the z bias."""
    n = int(round(seconds * RATE_HZ))
    simulator = ImuSimulator(MotionProfile([still(seconds)]), rate_hz=RATE_HZ, sensor=sensor, seed=seed,
                             n_samples=n, start_us=_START_US)
    yaw = np.unwrap(fuse_simulation(simulator, n, **fusion_settings)[:, 0], period=360.0)
    t = np.arange(n) / RATE_HZ
    keep = t >= 5.0
    return YawDrift(simulator.gyro_bias_dps, float(np.polyfit(t[keep], yaw[keep], 1)[0] * 60.0))
