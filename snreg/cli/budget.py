"""``snreg budget``: the error budget of the phantom experiment (:mod:`snreg.simulation.budget`); wired into
``snreg.cli`` by :func:`add_budget_parser`.

``--errors`` names the error model (ideal, thesis or a YAML file, :mod:`snreg.demo.errors`); ``--set SOURCE=FACTOR``
scales one source's error (0 switches it off) and ``--set SOURCE.PARAMETER=VALUE`` changes one magnitude; a bad
name or value is one line on stderr and exit status 2, before any work.
"""

from __future__ import annotations

import json
import shlex
import sys
import time

from snreg.cli.common import check_output_folder, int_range, progress, seed, workers
from snreg.errors import UserError

__all__ = ["add_budget_parser", "cmd_budget", "DEFAULT_REPS"]

DEFAULT_REPS = 100         # snreg.simulation.budget.DEFAULT_REPS, stated here so the parser imports no numpy
MAX_REPS = 10_000          # about two hours on 2 cores; beyond is a typing slip
MAX_DRAWS = 1000
_METHODS = ("icp", "cpd", "chamfer", "global")


def add_budget_parser(subparsers) -> None:
    p = subparsers.add_parser("budget", help="error budget of the phantom experiment: which source costs what",
                              description="Monte Carlo over the phantom experiment under an error model: every "
                                          "source alone, all together and all but one; about a minute on 2 cores.")
    p.add_argument("--errors", default="thesis", metavar="FILE",
                   help="error model: ideal, thesis (default) or a YAML file like resources/errors/thesis.yaml")
    p.add_argument("--reps", type=int_range(1, MAX_REPS), default=DEFAULT_REPS, help=f"repetitions (at most {MAX_REPS})")
    p.add_argument("--method", choices=_METHODS, default="chamfer", help="registration method (thesis: chamfer)")
    p.add_argument("--covariances", action="store_true",
                   help="register with each node's own covariance (as the rig gives it from the model's magnitudes) "
                        "and each hot spot's (as the segmentation gives it); global weighs nodes by them, the other "
                        "methods fit as without")
    p.add_argument("--set", action="append", default=None, metavar="SOURCE=VALUE", dest="settings",
                   help="what if: SOURCE=FACTOR scales a source's error (0: off), SOURCE.PARAMETER=VALUE sets one "
                        "magnitude, e.g. --set tracking=0.5 --set imu.turn_error_deg=0.2")
    p.add_argument("-o", "--output", default="snreg-budget", help="report folder (budget.md, tornado.png, budget.json)")
    p.add_argument("--json", action="store_true", help='print one JSON object: {"all", "alone", "all_but", '
                   '"tre_predicted_mm", "dominant"}; each figure: rms_mm, node_error_mm, pairing_success, coverage_90')
    p.add_argument("--cohort", nargs="?", const="synthetic", metavar="DIR",
                   help="over patient-like node sets instead of the phantom: the synthetic 13-patient cohort of snreg "
                        "simulate, or a directory of preop node CSVs, one per patient")
    p.add_argument("--seed", type=seed, default=0, help="random seed")
    p.add_argument("--draws", type=int_range(1, MAX_DRAWS), default=6,
                   help=f"rendered-tracking draws the repetitions share (at most {MAX_DRAWS})")
    p.add_argument("--workers", type=workers, default=0, help="processes, at most one per core (0: one per core)")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.set_defaults(func=cmd_budget)


def cmd_budget(args) -> int:
    from snreg.demo.errors import load_error_model
    from snreg.simulation.budget import BudgetConfig, run_budget
    from snreg.simulation.budget_report import coverage_line, format_table, phantom_gap, write_budget_report

    try:
        model = load_error_model(args.errors)
        for setting in args.settings or ():
            model = model.with_setting(setting)
        cohort = _cohort(args.cohort) if args.cohort else ()
    except ValueError as err:
        raise UserError(str(err)) from None
    check_output_folder(args.output, "budget report")
    config = BudgetConfig(reps=args.reps, method=args.method, seed=args.seed, draws=args.draws, workers=args.workers,
                          cohort=cohort, covariances=args.covariances)
    started = time.perf_counter()
    result = run_budget(model, config, progress=None if args.quiet else progress("budget"))
    seconds = time.perf_counter() - started
    command = "snreg " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    try:
        paths = write_budget_report(result, args.output, command, seconds)
    except OSError as err:
        raise UserError(f"{args.output}: cannot write the report ({err.strerror or err})") from None
    if args.json:
        print(json.dumps(result.to_json()))
        return 0
    print(format_table(result))
    if result.dominant:
        print(f"\ndominant: {result.dominant} (without it {result.figures['all_but:' + result.dominant].rms_median:.2f}"
              f" mm instead of {result.figures['all'].rms_median:.2f} mm)")
    print(f"Fitzpatrick-West: FLE {result.fle_mm:.2f} mm -> TRE {result.tre_predicted_mm:.2f} mm, FRE "
          f"{result.fre_predicted_mm:.2f} mm; Monte Carlo TRE {result.tre_mc_mm:.2f} mm")
    print(coverage_line(result))
    if not config.cohort:
        print("\n".join(phantom_gap(result)))
    print(f"\nreport: {paths['markdown']}  chart: {paths['tornado']}  ({seconds:.0f} s)", file=sys.stderr)
    return 0


def _cohort(where: str) -> tuple:
    """(nodes, labels) per patient: the synthetic cohort, or the node CSVs in a directory (ValueError when bad)."""
    from snreg.simulation import load_cohort, synthetic_cohort

    patients = synthetic_cohort() if where == "synthetic" else load_cohort(where)
    return tuple((patient.nodes.xyz, tuple(patient.nodes.labels)) for patient in patients)
