"""Orientation of the 6-axis IMU (LSM6DSOX, no magnetometer) with imufusion >= 1.3 (thesis §2.4, §3.5).

:class:`Fusion` wraps ``imufusion.Ahrs`` (Madgwick's revised AHRS) and ``imufusion.Bias``
(run-time gyroscope offset estimation) and turns each :class:`~snreg.imu.protocol.ImuSample`
into (yaw, pitch, roll) in degrees per docs/design.md, Conventions: yaw about z, pitch about y, roll
about x, ``R = Rz @ Ry @ Rx``, where R is ``earth_from_sensor`` (imufusion's quaternion,
NWU earth frame: x north, y west, z up). At rest and level the accelerometer reads
+1 g on z and pitch = roll = 0.

Pitch and roll are referenced to gravity through the accelerometer; yaw has no reference
without a magnetometer, starts at 0 and drifts at the residual gyro bias about the
vertical. That residual is what the bias estimate is for: a constant 0.3 deg/s bias is
18 deg/min of yaw; after the initial still-period estimate it is a few hundredths of a
deg/min (``snreg.simulation.imu.measure_yaw_drift``).

imufusion behaviours worth knowing here: for the first 3 s after start (or after a
restart) the gain ramps down from 10 and ``update_no_magnetometer`` holds the heading at 0
(``status.initialising``); a gyro reading beyond 98% of ``gyroscope_range_dps`` restarts
the algorithm keeping the orientation but not the heading (``status.angular_rate_recovery``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import imufusion
import numpy as np
from scipy.spatial.transform import Rotation

from snreg.geometry import euler_from_rotation

if TYPE_CHECKING:
    from snreg.imu.protocol import ImuSample

__all__ = ["Fusion", "FusionStatus", "euler_of_wxyz", "fuse_arrays"]

_WRAP_US = 1 << 32            # the device clock is Arduino micros(): unsigned 32 bit, wraps after 71.6 min
_MAX_GAP_US = 1_000_000       # a larger step between device stamps is a device restart, not elapsed time


@dataclass(frozen=True)
class FusionStatus:
    """imufusion's flags and internal states after the last update.

    initialising: startup period (3 s): gain ramping down from 10, heading held at 0.
    angular_rate_recovery: the gyro exceeded the range; the algorithm restarted keeping the orientation.
    acceleration_recovery: the accelerometer was rejected longer than the rejection timeout and is used again.
    accelerometer_ignored: acceleration rejection active: the accelerometer disagreed with the
        estimated gravity by more than ``acceleration_rejection_deg`` (the sensor is accelerating).
    acceleration_error_deg: angle between measured and estimated gravity.
    acceleration_recovery_trigger: how far rejection has run towards the timeout, 0..1.
    bias_calibrated: the initial still-period bias estimate has been applied.
    """

    initialising: bool
    angular_rate_recovery: bool
    acceleration_recovery: bool
    accelerometer_ignored: bool
    acceleration_error_deg: float
    acceleration_recovery_trigger: float
    bias_calibrated: bool


class Fusion:
    """6-axis orientation filter: imufusion AHRS plus gyroscope bias correction.

    sample_rate_hz: nominal output data rate (208 Hz for the thesis LSM6DSOX set-up). imufusion
        uses it for its timeouts and the bias filter; each update integrates over the actual
        time between device timestamps.
    gain: 0.5, imufusion's recommended value. The accelerometer pulls the tilt towards gravity
        with a time constant of 1/gain = 2 s: short enough to cancel the tilt drift of a
        residual bias (steady tilt error = residual / gain, < 0.01 deg after calibration),
        long enough that the ~1 mg accelerometer noise moves tilt by < 0.01 deg.
    gyroscope_range_dps: the configured full scale, 125 deg/s on the thesis LSM6DSOX (its finest
        resolution, 4.375 mdps/LSB; an endoscope turns far slower). Replays of other sensors pass
        theirs (e.g. 2000); 0 disables the check (unclipped simulations). imufusion restarts when a
        reading passes 98% of it.
    acceleration_rejection_deg: 10 deg, imufusion's recommended value: while measured gravity is
        off the estimate by more than this the sensor is being accelerated and the accelerometer
        is ignored, so a jolt of the robot arm does not tilt the estimate.
    rejection_timeout_s: 5 s (imufusion 1.3's ``rejection_timeout``, formerly the recovery trigger
        period): after this much rejection the accelerometer is trusted again, so a wrong
        orientation (e.g. after a restart while moving) cannot persist.
    bias_correction: estimate and subtract the gyroscope bias (``imufusion.Bias``, a 0.02 Hz
        high-pass while still) and, at start, the mean over an initial still period. Off only
        to measure what it buys.
    bias_stationary_threshold_dps: 0.5 deg/s (imufusion's default is 3): the sensor counts as still
        while every bias-corrected axis is below it, and only then does the run-time estimate move
        (towards the corrected rate, with a 0.02 Hz high-pass). A turn slower than the threshold held
        longer than the stationary period cannot be told from bias and is partly learnt as bias, and
        every motion leaks into the estimate while it starts up through the threshold; at 3 deg/s a
        12 deg pan at 0.4 deg/s lost 10 deg and each 10 deg protractor turn shifted the estimate by
        ~0.02 deg/s; at 0.5 deg/s the pan lost 0.6 deg and the leak is negligible. 0.5 is ~5 sigma of
        the LSM6DSOX per-sample gyro noise at 208 Hz (sigma 0.05-0.1 deg/s), so rest still counts
        as rest. It needs the initial estimate below: a raw zero-rate offset above 0.5 deg/s
        (LSM6DSOX: +-1 deg/s typical) never looks still to the run-time estimate.
    bias_stationary_period_s: 3 s (imufusion's default): how long the sensor must be still before
        the run-time estimate moves, so pauses within a motion do not count as rest. Longer periods
        barely reduce the slow-motion loss and at the noisier end of the LSM6DSOX never see rest.
    initial_bias_period_s: 3 s: if the sensor is still (every axis within the stationary threshold
        of its mean) for this long from the first sample, the bias is set to the mean gyro over it
        (~0.002 deg/s standard error at 208 Hz); imufusion's run-time estimate alone needs ~30 s at
        rest to bring a 0.3 deg/s bias to 0.01 deg/s. 3 s matches imufusion's startup, during which
        the heading is held at 0 anyway, so the yaw never integrates the raw bias. So hold the sensor
        still for the first 3 s; ``status.bias_calibrated`` tells whether it was (the check cannot
        tell a perfectly steady turn from bias). 0 disables it.
    """

    def __init__(self, sample_rate_hz: float, *, gain: float = 0.5, gyroscope_range_dps: float = 125.0,
                 acceleration_rejection_deg: float = 10.0, rejection_timeout_s: float = 5.0,
                 bias_correction: bool = True, bias_stationary_threshold_dps: float = 0.5,
                 bias_stationary_period_s: float = 3.0, initial_bias_period_s: float = 3.0):
        if not sample_rate_hz > 0:
            raise ValueError(f"IMU sample rate must be positive, got {sample_rate_hz} Hz")
        self.sample_rate_hz = float(sample_rate_hz)
        self.settings = imufusion.AhrsSettings(
            sample_rate=self.sample_rate_hz,
            convention=imufusion.CONVENTION_NWU,
            gain=gain,
            gyroscope_range=gyroscope_range_dps,
            acceleration_rejection=acceleration_rejection_deg,
            magnetic_rejection=0.0,            # no magnetometer (0 disables the feature)
            rejection_timeout=rejection_timeout_s,
        )
        self._ahrs = imufusion.Ahrs()
        self._ahrs.set_settings(self.settings)
        self._bias = None
        if bias_correction:
            self._bias = imufusion.Bias()
            self._bias.set_settings(imufusion.BiasSettings(sample_rate=self.sample_rate_hz,
                                                           stationary_threshold=bias_stationary_threshold_dps,
                                                           stationary_period=bias_stationary_period_s))
        self._still_threshold = float(bias_stationary_threshold_dps)
        self._initial_n = int(round(initial_bias_period_s * self.sample_rate_hz)) if bias_correction else 0
        self._initial_count = 0                # raw gyro (deg/s) of the initial still period: count, sum, min, max
        self._initial_sum = np.zeros(3)
        self._initial_min = np.full(3, np.inf)
        self._initial_max = np.full(3, -np.inf)
        self._bias_calibrated = False
        self._last_device_us = None

    def update(self, sample: ImuSample) -> tuple[float, float, float]:
        """Fuse one sample; returns (yaw, pitch, roll) in degrees (use :meth:`advance` when the angles are not needed)."""
        self.advance(sample)
        return self.euler

    def advance(self, sample: ImuSample) -> None:
        """Fuse one sample without computing angles (the live 208 Hz path: angles are read when shown).

        The integration step is the time since the previous sample on the device clock
        (microseconds, modulo 2**32). The first sample, a repeated stamp, or a step over 1 s
        (a device restart) integrate over the nominal period instead.
        """
        self._advance(int(sample.t_device_us), sample.accel_g, sample.gyro_dps)

    def _advance(self, t_device_us: int, accel_g, gyro_dps) -> None:
        if self._last_device_us is None:
            dt = 1.0 / self.sample_rate_hz
        else:
            step_us = (t_device_us - self._last_device_us) % _WRAP_US
            dt = step_us * 1e-6 if 0 < step_us <= _MAX_GAP_US else 1.0 / self.sample_rate_hz
        self._last_device_us = t_device_us
        self._step(gyro_dps, accel_g, dt)

    def update_block(self, t_device_us, accel_g, gyro_dps) -> np.ndarray:
        """Fuse samples in order (device times (n,) us, accel (n, 3) g, gyro (n, 3) deg/s) exactly as :meth:`update`
        would one by one; returns (n, 3) yaw, pitch, roll in degrees, converted in one batch (recordings)."""
        quaternions = np.empty((len(t_device_us), 4))
        for k, (t_us, accel, gyro) in enumerate(zip(t_device_us, accel_g, gyro_dps)):
            self._advance(int(t_us), accel, gyro)
            quaternions[k] = self._ahrs.get_quaternion()
        return euler_of_wxyz(quaternions)

    def step(self, gyro_dps: np.ndarray, accel_g: np.ndarray, dt_s: float) -> tuple[float, float, float]:
        """Fuse one reading (gyro (3,) deg/s, accel (3,) g) taken ``dt_s`` seconds after the last; returns the angles."""
        self._step(gyro_dps, accel_g, dt_s)
        return self.euler

    def _step(self, gyro_dps, accel_g, dt_s: float) -> None:
        gyro = np.asarray(gyro_dps, dtype=float)
        if self._bias is not None:
            self._calibrate_initial(gyro)
            gyro = self._bias.update(gyro)
        self._ahrs.set_sample_period(dt_s)
        self._ahrs.update_no_magnetometer(gyro, np.asarray(accel_g, dtype=float))

    @property
    def euler(self) -> tuple[float, float, float]:
        """(yaw, pitch, roll) in degrees now (docs/design.md, Conventions convention)."""
        return euler_from_rotation(self.earth_from_sensor)

    def _calibrate_initial(self, gyro: np.ndarray) -> None:
        """Collect the first ``initial_bias_period_s`` of gyro; if it was still, its mean is the bias."""
        if self._initial_count >= self._initial_n:
            return
        self._initial_count += 1
        self._initial_sum += gyro
        self._initial_min = np.minimum(self._initial_min, gyro)
        self._initial_max = np.maximum(self._initial_max, gyro)
        if self._initial_count == self._initial_n:
            mean = self._initial_sum / self._initial_n
            if np.all(self._initial_max - mean < self._still_threshold) and np.all(mean - self._initial_min < self._still_threshold):
                self._bias.set_offset(mean)
                self._bias_calibrated = True

    @property
    def quaternion_wxyz(self) -> np.ndarray:
        """(4,) current orientation, sensor to earth (NWU), as imufusion gives it: a unit quaternion w, x, y, z (scalar
        first; scipy's is last). The live 208 Hz path keeps these as they come: a scipy Rotation per sample cost
        more than the fusion itself."""
        return self._ahrs.get_quaternion()

    @property
    def rotation(self) -> Rotation:
        """Current orientation, sensor to earth (NWU), as a scipy Rotation."""
        w, x, y, z = self._ahrs.get_quaternion()
        return Rotation.from_quat([x, y, z, w])

    @property
    def earth_from_sensor(self) -> np.ndarray:
        """(3, 3) rotation mapping sensor-frame vectors to the earth frame."""
        return self.rotation.as_matrix()

    @property
    def bias_dps(self) -> np.ndarray:
        """(3,) current gyroscope bias estimate in deg/s (zeros when bias correction is off)."""
        return np.zeros(3) if self._bias is None else np.asarray(self._bias.get_offset(), dtype=float)

    @property
    def status(self) -> FusionStatus:
        """imufusion's flags and internal states now, and whether the initial bias estimate was applied."""
        flags, states = self._ahrs.get_flags(), self._ahrs.get_internal_states()
        return FusionStatus(
            initialising=bool(flags.startup),
            angular_rate_recovery=bool(flags.overrange_recovery),
            acceleration_recovery=bool(flags.acceleration_recovery),
            accelerometer_ignored=bool(states.accelerometer_ignored),
            acceleration_error_deg=float(states.acceleration_error),
            acceleration_recovery_trigger=float(states.acceleration_recovery_trigger),
            bias_calibrated=self._bias_calibrated,
        )


def fuse_arrays(t_s: np.ndarray, gyro_dps: np.ndarray, accel_g: np.ndarray, *,
                sample_rate_hz: float | None = None, **settings) -> np.ndarray:
    """Offline fusion of a recording: returns (N, 3) (yaw, pitch, roll) in degrees.

    t_s: (N,) sample times in seconds; gyro_dps, accel_g: (N, 3). Each sample integrates over the
    time since the previous one (the first over the nominal period). ``sample_rate_hz`` defaults
    to 1 / median step; ``settings`` are :class:`Fusion`'s keyword arguments.
    """
    t_s = np.asarray(t_s, dtype=float)
    gyro_dps = np.asarray(gyro_dps, dtype=float)
    accel_g = np.asarray(accel_g, dtype=float)
    if t_s.ndim != 1 or gyro_dps.shape != (len(t_s), 3) or accel_g.shape != (len(t_s), 3):
        raise ValueError(f"need t (N,), gyro (N, 3) and accel (N, 3); got {t_s.shape}, {gyro_dps.shape}, {accel_g.shape}")
    if sample_rate_hz is None:
        if len(t_s) < 2:
            raise ValueError("need two samples or sample_rate_hz to know the sample rate")
        sample_rate_hz = 1.0 / float(np.median(np.diff(t_s)))
    fusion = Fusion(sample_rate_hz, **settings)
    dt = np.diff(t_s, prepend=t_s[0] - 1.0 / sample_rate_hz)
    quaternions = np.empty((len(t_s), 4))
    for k, (g, a, d) in enumerate(zip(gyro_dps, accel_g, dt)):
        fusion._step(g, a, d)
        quaternions[k] = fusion._ahrs.get_quaternion()
    return euler_of_wxyz(quaternions)


def euler_of_wxyz(quaternions: np.ndarray) -> np.ndarray:
    """(n, 3) yaw, pitch, roll in degrees of imufusion quaternions (n, 4) given as w, x, y, z (no detour through a
    matrix, which scipy must make orthonormal first: the live path's angles come from here)."""
    if len(quaternions) == 0:
        return np.zeros((0, 3))
    return Rotation.from_quat(np.asarray(quaternions)[:, [1, 2, 3, 0]]).as_euler("ZYX", degrees=True)
