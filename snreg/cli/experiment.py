"""``snreg experiment tracking|camera|tissue-pivot|imu``: the thesis' tracking (Table 4) and IMU (Fig. 19) accuracy
experiments, the camera's insertion tracked on rendered surgery videos, and the pivot distance from rendered turns
over tissue."""

from __future__ import annotations

import argparse
import sys

from snreg.cli.common import finite_float, float_range, floats, int_range, ints, positive_int, progress, seed

__all__ = ["add_experiment_parser"]

MAX_FRAMES = 10_000


def _frames(text: str) -> int:
    value = positive_int(text)
    if not 2 <= value <= MAX_FRAMES:
        raise argparse.ArgumentTypeError(f"expected 2 (the spread needs two) to {MAX_FRAMES} frames per position, "
                                         f"got {value}")
    return value


def _noise(text: str) -> float:
    value = finite_float(text)
    if not 0 <= value <= 255:
        raise argparse.ArgumentTypeError(f"expected a noise sigma from 0 to 255 grey levels, got {text!r}")
    return value


def _turns(text: str) -> tuple[float, ...]:
    values = floats(text)
    if not values or not all(0 < v <= 60 for v in values):
        raise argparse.ArgumentTypeError(f"expected turns above 0 and at most 60 degrees, comma-separated, got {text!r}")
    return values


def add_experiment_parser(subparsers) -> None:
    p = subparsers.add_parser("experiment", help="accuracy experiments")
    experiments = p.add_subparsers(dest="experiment", required=True, metavar="EXPERIMENT")
    e = experiments.add_parser("tracking", help="thesis Table 4 on rendered frames",
                               description="The thesis' tracking experiment (Table 4) on rendered 1920x1080 frames: "
                                           "6 depth bands x 4 positions x FRAMES noisy frames, three trackers "
                                           "(the default 60 frames take about 20 minutes on 2 cores; progress on stderr).")
    e.add_argument("--frames", type=_frames, default=60, help="noisy frames per probe position (thesis: 60)")
    e.add_argument("--noise", type=_noise, default=3.0, help="sensor noise sigma, grey levels")
    e.add_argument("--seed", type=seed, default=0, help="seed of the renders and the noise")
    e.set_defaults(func=cmd_experiment_tracking)
    e = experiments.add_parser("camera", help="the insertion tracker on rendered surgery videos",
                               description="The camera's insertion tracked (as 'snreg track-camera') on rendered "
                                           "videos of the thesis' rig whose truth is known: the camera sliding +-40 mm "
                                           "and turning up to 30 degrees about the pivot and back, the probe in view, "
                                           "some pairs covered or blurred (about 2 minutes per 100 full-HD pairs).")
    e.add_argument("--seeds", type=ints, default=(1, 2, 3), metavar="S,S,...",
                   help="one video per seed: its tissue, texture, motion and noise (default 1,2,3)")
    e.add_argument("--pairs", type=int_range(10, 2000, "pairs"), default=100, help="pairs per video (about)")
    e.add_argument("--scale", type=float_range(0.2, 1.0, low_open=False), default=1.0,
                   help="render at this fraction of 1920x1080 (default 1: full HD)")
    e.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    e.set_defaults(func=cmd_experiment_camera)
    e = experiments.add_parser("tissue-pivot", help="the pivot distance from rendered turns over tissue",
                               description="The trocar-camera distance calibrated from the camera turning about the "
                                           "trocar over tissue (as 'snreg calibrate trocar tissue'), on rendered turns "
                                           "of the thesis' rig whose truth is known: per seed a distance of 130-180 mm "
                                           "and its own tissue, the probe in view, the IMU at 0.2 degrees of noise; "
                                           "each turn spread in --turns (about 30 s per turn of 36 pairs at half "
                                           "size; progress on stderr).")
    e.add_argument("--seeds", type=ints, default=(1, 2, 3), metavar="S,S,...",
                   help="one scene per seed: distance, tissue, texture and noise (default 1,2,3)")
    e.add_argument("--turns", type=_turns, default=(20.0, 12.0, 8.0, 4.0), metavar="DEG,DEG,...",
                   help="the shaft's orientation spread of each recording, degrees (default 20,12,8,4)")
    e.add_argument("--pairs", type=int_range(12, 400, "pairs"), default=36, help="pairs per turn (default 36)")
    e.add_argument("--scale", type=float_range(0.2, 1.0, low_open=False), default=0.5,
                   help="render at this fraction of 1920x1080 (default 0.5)")
    e.add_argument("--json", action="store_true", help="print the trials and the summary per turn as one JSON object")
    e.set_defaults(func=cmd_experiment_tissue_pivot)
    e = experiments.add_parser("imu", help="thesis Fig. 19: simulated protractor rotations")
    e.add_argument("--seed", type=seed, default=0, help="seed of the simulated sensor")
    e.set_defaults(func=cmd_experiment_imu)


def cmd_experiment_tracking(args) -> int:
    from snreg.camera import thesis_calibration
    from snreg.probe import default_probe_model
    from snreg.simulation import tracking as tracking_study

    print(f"tracking experiment: {len(tracking_study.THESIS_BANDS)} depth bands x 4 positions x {args.frames} frames",
          file=sys.stderr, flush=True)
    results = tracking_study.run_tracking_experiment(thesis_calibration(), default_probe_model(),
                                                     tracking_study.THESIS_BANDS, frames=args.frames,
                                                     noise_sigma=args.noise, seed=args.seed,
                                                     progress=progress("tracking experiment: frames", always=True))
    print(tracking_study.format_table(results))
    return 0


def cmd_experiment_camera(args) -> int:
    import json

    from snreg.simulation import camera as camera_study

    trials = [camera_study.run_camera_trial(s, pairs=args.pairs, scale=args.scale,
                                            progress=progress(f"camera experiment, seed {s}: pairs", always=True))
              for s in args.seeds]
    if args.json:
        print(json.dumps({"trials": [camera_study.summary([t]) | {"seed": t.seed} for t in trials],
                          "all": camera_study.summary(trials)}))
    else:
        print(camera_study.format_camera_table(trials))
    return 0


def cmd_experiment_tissue_pivot(args) -> int:
    import dataclasses
    import json

    from snreg.simulation import tissue_pivot as study

    trials = [study.run_tissue_pivot_trial(s, turn, pairs=args.pairs, scale=args.scale,
                                           progress=progress(f"tissue pivot, seed {s}, turn {turn:g}: pairs", always=True))
              for turn in args.turns for s in args.seeds]
    if args.json:
        print(json.dumps({"trials": [dataclasses.asdict(t) | {"error_mm": t.error_mm} for t in trials],
                          "turns": {f"{turn:g}": study.summary([t for t in trials if t.turn_deg == turn])
                                    for turn in args.turns}}))
    else:
        print(study.format_tissue_pivot_table(trials))
    return 0


def cmd_experiment_imu(args) -> int:
    from snreg.simulation import imu as imu_study

    print(imu_study.format_table(imu_study.run_protractor_experiment(seed=args.seed)))
    with_bias = imu_study.measure_yaw_drift(seed=args.seed)
    without = imu_study.measure_yaw_drift(seed=args.seed, bias_correction=False)
    print(f"\nyaw drift of a still sensor (no magnetometer), z gyro bias {with_bias.bias_dps[2]:+.3f} deg/s: "
          f"{with_bias.deg_per_min:+.3f} deg/min with bias correction, "
          f"{without.deg_per_min:+.3f} deg/min without")
    return 0
