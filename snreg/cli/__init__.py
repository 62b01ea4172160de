"""``snreg``: the command line (DESIGN.md §4); one module per subcommand, this one only builds the parser.

Errors a user can cause (:class:`~snreg.errors.UserError`) end as one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import sys

from snreg import __version__
from snreg.cli.bench import add_bench_parser
from snreg.cli.calibrate import add_calibrate_parser
from snreg.cli.demo import add_demo_parser
from snreg.cli.experiment import add_experiment_parser
from snreg.cli.imu import add_imu_parser
from snreg.cli.preop import add_preop_parser
from snreg.cli.register import add_register_parser
from snreg.cli.session import add_session_parser
from snreg.cli.simulate import add_simulate_parser
from snreg.cli.track import add_track_parser
from snreg.cli.trocar import add_trocar_parser
from snreg.errors import UserError

__all__ = ["main", "build_parser", "EXIT_BAD_INPUT"]

EXIT_BAD_INPUT = 2


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="snreg", description="Sentinel-node registration tools.")
    parser.add_argument("--version", action="version", version=f"snreg {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    add_register_parser(sub)
    add_simulate_parser(sub)
    add_trocar_parser(add_calibrate_parser(sub))
    add_imu_parser(sub)
    add_preop_parser(sub)
    add_session_parser(sub)
    add_demo_parser(sub)
    add_track_parser(sub)
    add_experiment_parser(sub)
    add_bench_parser(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except UserError as err:
        print(f"snreg: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
