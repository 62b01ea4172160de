"""``snreg experiment tracking|imu``: the thesis' tracking (Table 4) and IMU (Fig. 19) accuracy experiments."""

from __future__ import annotations

import sys

from snreg.camera import thesis_calibration
from snreg.errors import UserError
from snreg.probe import default_probe_model
from snreg.simulation import imu as imu_study
from snreg.simulation import tracking as tracking_study

__all__ = ["add_experiment_parser"]


def add_experiment_parser(subparsers) -> None:
    p = subparsers.add_parser("experiment", help="accuracy experiments")
    experiments = p.add_subparsers(dest="experiment", required=True)
    e = experiments.add_parser("tracking", help="thesis Table 4 on rendered frames")
    e.add_argument("--frames", type=int, default=60, help="noisy frames per probe position (thesis: 60)")
    e.add_argument("--noise", type=float, default=3.0, help="sensor noise sigma, grey levels")
    e.add_argument("--seed", type=int, default=0)
    e.set_defaults(func=cmd_experiment_tracking)
    e = experiments.add_parser("imu", help="thesis Fig. 19: simulated protractor rotations")
    e.add_argument("--seed", type=int, default=0)
    e.set_defaults(func=cmd_experiment_imu)


def cmd_experiment_tracking(args) -> int:
    if args.frames < 2:
        raise UserError("--frames must be at least 2")

    def progress(done, total):
        print(f"\rtracking experiment: {done}/{total} positions", end="" if done < total else "\n",
              file=sys.stderr, flush=True)

    results = tracking_study.run_tracking_experiment(thesis_calibration(), default_probe_model(),
                                                     tracking_study.THESIS_BANDS, frames=args.frames,
                                                     noise_sigma=args.noise, seed=args.seed, progress=progress)
    print(tracking_study.format_table(results))
    return 0


def cmd_experiment_imu(args) -> int:
    print(imu_study.format_table(imu_study.run_protractor_experiment(seed=args.seed)))
    with_bias = imu_study.measure_yaw_drift(seed=args.seed)
    without = imu_study.measure_yaw_drift(seed=args.seed, bias_correction=False)
    print(f"\nyaw drift of a still sensor (no magnetometer), z gyro bias {with_bias.bias_dps[2]:+.3f} deg/s: "
          f"{with_bias.deg_per_min:+.3f} deg/min with bias correction, "
          f"{without.deg_per_min:+.3f} deg/min without")
    return 0
