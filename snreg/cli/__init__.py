"""``snreg``: the command line (docs/design.md, Contracts); one module per subcommand, this one only builds the parser.

Errors a user can cause (:class:`~snreg.errors.UserError`, argparse's own) end as one line on stderr and exit
status 2, with nothing written. Building the parser imports only argparse-level modules, so ``snreg --help``
starts at once; each subcommand imports numpy, OpenCV and the rest when it runs. A closed pipe
(``snreg ... | head``) ends quietly; an output that cannot be written (``> /dev/full``) in one line.
"""

from __future__ import annotations

import errno
import os
import sys
import warnings

from snreg import __version__
from snreg.cli.bench import add_bench_parser
from snreg.cli.budget import add_budget_parser
from snreg.cli.calibrate import add_calibrate_parser
from snreg.cli.common import Parser
from snreg.cli.demo import add_demo_parser
from snreg.cli.experiment import add_experiment_parser
from snreg.cli.imu import add_imu_parser
from snreg.cli.preop import add_preop_parser
from snreg.cli.register import add_register_parser
from snreg.cli.session import add_session_parser
from snreg.cli.simulate import add_simulate_parser
from snreg.cli.track import add_track_parser
from snreg.cli.track_camera import add_track_camera_parser
from snreg.cli.trocar import add_trocar_parser
from snreg.errors import UserError

__all__ = ["main", "build_parser", "EXIT_BAD_INPUT"]

EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
EXIT_CLOSED_PIPE = 1          # as Python's own documentation recommends for a reader that went away


def build_parser() -> Parser:
    parser = Parser(prog="snreg", description="Sentinel-node registration tools.")
    parser.add_argument("--version", action="version", version=f"snreg {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_register_parser(sub)
    add_simulate_parser(sub)
    add_trocar_parser(add_calibrate_parser(sub))
    add_imu_parser(sub)
    add_preop_parser(sub)
    add_session_parser(sub)
    add_demo_parser(sub)
    add_track_parser(sub)
    add_track_camera_parser(sub)
    add_experiment_parser(sub)
    add_bench_parser(sub)
    add_budget_parser(sub)
    return parser


def main(argv=None) -> int:
    """Run ``snreg`` with ``argv`` (default: the command line); returns the exit status."""
    _quiet_opencv()
    if not sys.warnoptions:             # numpy's and pydicom's warnings are not ours to print: snreg says what matters
        warnings.simplefilter("ignore")
    try:
        args = build_parser().parse_args(argv)         # argparse's errors: one line and exit 2 (common.Parser)
        status = args.func(args)
        sys.stdout.flush()
        return status
    except UserError as err:
        print(f"snreg: {' '.join(str(err).split())}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except BrokenPipeError:
        _drop_stdout()
        return EXIT_CLOSED_PIPE
    except KeyboardInterrupt:
        print("snreg: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except OSError as err:
        if err.filename is not None or err.errno not in (errno.ENOSPC, errno.EIO, errno.EFBIG, errno.EDQUOT):
            raise
        _drop_stdout()
        print(f"snreg: cannot write the output ({err.strerror})", file=sys.stderr)
        return EXIT_BAD_INPUT


def _quiet_opencv() -> None:
    """Keep OpenCV's own ``[ WARN ]``/``[ERROR]`` log lines off stderr: snreg reports its errors itself."""
    os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
    cv2 = sys.modules.get("cv2")
    if cv2 is not None:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)


def _drop_stdout() -> None:
    """Point stdout at /dev/null so that the interpreter's last flush does not fail once more."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass        # not a real file (e.g. captured by a test): nothing left to flush
