"""``snreg simulate``: the thesis' registration simulation study (§5.4) on a cohort; report, trial CSV and plots."""

from __future__ import annotations

import argparse
import shlex
import sys

from snreg.cli.common import check_output_folder, float_range, floats, int_range, ints, seed, workers
from snreg.errors import UserError

__all__ = ["add_simulate_parser", "cmd_simulate", "DEFAULTS"]

# snreg.simulation.study's defaults, stated here so that building the parser imports no numpy (a test keeps them equal)
DEFAULTS = {"reps": 25, "sigmas": (2.0, 5.0, 10.0, 15.0, 20.0), "extras": (0, 1, 2, 3),
            "methods": ("icp", "cpd", "chamfer", "global")}


MAX_REPS = 10_000            # 400 times the default study: days on 2 cores
MAX_SIGMA_MM = 1000.0        # beyond any intraop error; larger ones overflow the fits


def _sigmas(text: str) -> tuple[float, ...]:
    values = floats(text)
    if not values or min(values) <= 0 or max(values) > MAX_SIGMA_MM:
        raise argparse.ArgumentTypeError(f"expected error sigmas above 0 and at most {MAX_SIGMA_MM:g} mm, e.g. 2,5,10, "
                                         f"got {text!r}")
    return values


def _extras(text: str) -> tuple[int, ...]:
    values = ints(text)
    if not values or min(values) < 0:
        raise argparse.ArgumentTypeError(f"expected node counts >= 0, e.g. 0,1,2, got {text!r}")
    return values


def _methods(text: str) -> tuple[str, ...]:
    specs = tuple(s.strip() for s in (text.split(";") if ";" in text else text.split(",")) if s.strip())
    if not specs:
        raise argparse.ArgumentTypeError(f"expected method specs, e.g. icp,global or 'cpd:w=0;cpd:w=0.1', got {text!r}")
    return specs


def add_simulate_parser(subparsers) -> None:
    p = subparsers.add_parser("simulate", help="the thesis' registration simulation study on a cohort",
                              description="The thesis' simulation study (§5.4): every patient x sigma x extras x "
                                          "repetition, every method; about 2 minutes with the defaults on 2 cores.")
    p.add_argument("--reps", type=int_range(1, MAX_REPS), default=DEFAULTS["reps"],
                   help="repetitions per patient, sigma and extras")
    p.add_argument("--sigmas", type=_sigmas, default=DEFAULTS["sigmas"], help="intraop error sigma per axis, mm")
    p.add_argument("--extras", type=_extras, default=DEFAULTS["extras"], help="numbers of extra intraop nodes")
    p.add_argument("--missing", type=_extras, default=(0,),
                   help="numbers of SPECT nodes not found intraop, e.g. 0,1,2 (0: the thesis' protocol); with any above "
                        "0 the report adds accuracy per missing count, target-error coverage and the incremental scenario")
    p.add_argument("--methods", type=_methods, default=DEFAULTS["methods"],
                   help="e.g. icp,cpd,chamfer,global,global+labels (';' to separate specs with options, e.g. 'cpd:w=0.1')")
    p.add_argument("--anisotropy", type=float_range(1.0, 50.0, low_open=False), default=1.0, metavar="R",
                   help="each intraop node's error along its own viewing ray is R times its error across it (per-axis "
                        "RMS still sigma; 1: the thesis' isotropic error); '+cov' methods are given the covariances")
    p.add_argument("--landmarks", type=int_range(0, 6), default=0, metavar="K",
                   help="K anatomical landmarks per trial (aortic bifurcation, common iliac bifurcations, top of the "
                        "pubic symphysis, internal iliac origins, in that order), given to '+landmarks' methods")
    p.add_argument("--landmark-sd", type=float_range(0.0, 50.0, "mm"), default=2.0, metavar="MM",
                   help="each landmark pair's own error, mm per axis (default 2)")
    p.add_argument("--max-nodes", type=int_range(1, 50), metavar="N",
                   help="cut every patient down to N SPECT nodes (1 or 2: patients the thesis' method cannot register)")
    p.add_argument("--swap-landmarks", action="store_true",
                   help="exchange the first two landmarks' names intraop (a wrong name): how often it is flagged")
    p.add_argument("--start", choices=("rough", "gravity"), default="rough",
                   help="rough: the thesis' rough alignment (up to 30 degrees per axis, 20 mm); gravity: the preop set "
                        "turned any way and shifted up to 300 mm, registration given down in both frames (the table "
                        "tilted 30 degrees head down)")
    p.add_argument("--tilt-sd", type=float_range(0.0, 45.0, "degrees", low_open=False), default=8.0, metavar="DEG",
                   help="gravity start: error of the entered table tilt (default 8)")
    p.add_argument("--imu-down-sd", type=float_range(0.0, 45.0, "degrees", low_open=False), default=1.0,
                   metavar="DEG", help="gravity start: error of the IMU's down (default 1)")
    p.add_argument("--cohort", help="directory of preop node CSVs, one per patient (default: synthetic cohort)")
    p.add_argument("--seed", type=seed, default=0, help="random seed of the study")
    p.add_argument("--workers", type=workers, default=0, help="processes, at most one per core (0: one per core)")
    p.add_argument("-o", "--output", default="snreg-simulation", help="report directory")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.set_defaults(func=cmd_simulate)


def cmd_simulate(args) -> int:
    from snreg.registration._problem import MAX_NODES
    from snreg.simulation import StudyConfig, load_cohort, run_study, synthetic_cohort, write_report
    from snreg.simulation.report import claims_table, coverage_table, missing_table, table6
    from snreg.simulation.study import check_method

    check_output_folder(args.output, "report")
    try:
        for spec in args.methods:
            check_method(spec)
        patients = load_cohort(args.cohort) if args.cohort else synthetic_cohort()
    except ValueError as err:
        raise UserError(str(err)) from None
    if args.max_nodes is not None and args.max_nodes < 3 and not args.landmarks:
        raise UserError(f"--max-nodes {args.max_nodes} needs --landmarks: without landmarks fewer than 3 nodes cannot "
                        "be registered")
    largest = max(patients, key=lambda patient: len(patient.nodes))
    if len(largest.nodes) - max(args.missing) < 3:
        raise UserError(f"--missing {max(args.missing)}: the largest patient ({largest.name}) has {len(largest.nodes)} "
                        "nodes and at least 3 must remain found; give smaller counts")
    if len(largest.nodes) + max(args.extras) > MAX_NODES:
        raise UserError(f"{largest.name} has {len(largest.nodes)} nodes, with {max(args.extras)} extras "
                        f"{len(largest.nodes) + max(args.extras)}: registration handles at most {MAX_NODES} per set")
    config = StudyConfig(methods=tuple(args.methods), sigmas=args.sigmas, extras=args.extras, reps=args.reps,
                         seed=args.seed, workers=args.workers, missing=tuple(args.missing), anisotropy=args.anisotropy,
                         landmarks=args.landmarks, landmark_sd=args.landmark_sd, max_nodes=args.max_nodes,
                         swap_landmarks=args.swap_landmarks, start=args.start, tilt_sd_deg=args.tilt_sd,
                         imu_down_sd_deg=args.imu_down_sd)
    study = run_study(patients, config, progress=not args.quiet)
    command = "snreg " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    try:
        paths = write_report(study, args.output, command)
    except OSError as err:
        raise UserError(f"{args.output}: cannot write the report ({err.strerror or err})") from None
    print(table6(study))
    if config.incremental:
        print("\n" + missing_table(study) + "\n\n" + claims_table(study) + "\n\n" + coverage_table(study))
    print(f"\nreport: {paths['markdown']}  trials: {paths['trials']}", file=sys.stderr)
    return 0
