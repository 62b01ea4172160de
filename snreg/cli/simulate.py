"""``snreg simulate``: the thesis' registration simulation study (§5.4) on a cohort; report, trial CSV and plots."""

from __future__ import annotations

import shlex
import sys

from snreg.cli.common import floats, ints
from snreg.errors import UserError
from snreg.simulation import StudyConfig, load_cohort, run_study, synthetic_cohort, write_report
from snreg.simulation.report import claims_table, coverage_table, missing_table, table6
from snreg.simulation.study import DEFAULT_EXTRAS, DEFAULT_METHODS, DEFAULT_REPS, DEFAULT_SIGMAS, parse_method

__all__ = ["add_simulate_parser", "cmd_simulate"]


def add_simulate_parser(subparsers) -> None:
    p = subparsers.add_parser("simulate", help="the thesis' registration simulation study on a cohort")
    p.add_argument("--reps", type=int, default=DEFAULT_REPS, help="repetitions per patient, sigma and extras")
    p.add_argument("--sigmas", type=floats, default=DEFAULT_SIGMAS, help="intraop error sigma per axis, mm")
    p.add_argument("--extras", type=ints, default=DEFAULT_EXTRAS, help="numbers of extra intraop nodes")
    p.add_argument("--missing", type=ints, default=(0,),
                   help="numbers of SPECT nodes not found intraop, e.g. 0,1,2 (default 0: the thesis' protocol); "
                        "with any above 0 the report adds accuracy per missing count, target-error coverage and the "
                        "incremental scenario")
    p.add_argument("--methods", type=lambda s: tuple(s.split(";") if ";" in s else s.split(",")),
                   default=DEFAULT_METHODS, help="e.g. icp,cpd,chamfer,global,global+labels (';' to separate specs with options)")
    p.add_argument("--cohort", help="directory of preop node CSVs, one per patient (default: synthetic cohort)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=0, help="processes (default: one per core)")
    p.add_argument("-o", "--output", default="snreg-simulation", help="report directory")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.set_defaults(func=cmd_simulate)


def cmd_simulate(args) -> int:
    try:
        for spec in args.methods:
            parse_method(spec)
        patients = load_cohort(args.cohort) if args.cohort else synthetic_cohort()
    except ValueError as err:
        raise UserError(str(err)) from None
    if args.reps < 1 or not args.sigmas or not args.extras or min(args.extras) < 0:
        raise UserError("--reps must be >= 1, --sigmas and --extras non-empty and extras >= 0")
    if not args.missing or min(args.missing) < 0:
        raise UserError("--missing must list counts >= 0, e.g. 0,1,2")
    config = StudyConfig(methods=tuple(args.methods), sigmas=args.sigmas, extras=args.extras, reps=args.reps,
                         seed=args.seed, workers=args.workers, missing=tuple(args.missing))
    study = run_study(patients, config, progress=not args.quiet)
    command = "snreg " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    paths = write_report(study, args.output, command)
    print(table6(study))
    if config.incremental:
        print("\n" + missing_table(study) + "\n\n" + claims_table(study) + "\n\n" + coverage_table(study))
    print(f"\nreport: {paths['markdown']}  trials: {paths['trials']}", file=sys.stderr)
    return 0
