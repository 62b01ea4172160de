"""``snreg-gui`` (and ``python -m snreg_gui``): the desktop app's command line. A wrong option or error model ends the
start in one line on stderr (exit 2) before any window opens."""

from __future__ import annotations

import argparse
import signal
import sys

from PySide6.QtCore import QTimer
from PySide6.QtWidgets import QApplication

from snreg.demo.errors import load_error_model
from snreg.demo.rig import DemoRig
from snreg_gui.app import MainWindow


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="snreg-gui", description="snreg acquisition, registration and review app")
    parser.add_argument("--demo", action="store_true", help="simulated devices, no hardware")
    parser.add_argument("--errors", metavar="ideal|thesis|FILE", help="with --demo: the error model the simulated rig "
                        "runs with (default ideal: nothing errs but the render's noise; thesis: the thesis' phantom)")
    parser.add_argument("--camera", choices=("still", "surgery"), help="with --demo: still (default), the camera never "
                        "moves; surgery, it slides through the trocar and turns about the pivot between nodes")
    parser.add_argument("session", nargs="?", help="session file: an existing one opens for review, a new name is "
                        "created for recording (demo default: a new file in the temp folder)")
    parser.add_argument("--replay", action="store_true", help="acquire from SESSION's recorded video and IMU at their "
                        "pace into a new session beside it")
    parser.add_argument("--speed", type=float, default=1.0, help="replay this many times faster (default 1)")
    args = parser.parse_args(argv)
    if args.replay and (not args.session or args.demo):
        parser.error("--replay needs the recorded SESSION.h5 to replay (and no --demo)")
    if not args.speed > 0:
        parser.error(f"--speed must be a positive number, not {args.speed}")
    if args.camera is not None and not args.demo:
        parser.error("--camera applies to the demo only; add --demo")
    errors = _error_model(parser, args)
    app = QApplication.instance() or QApplication(sys.argv[:1])
    rig = DemoRig(errors=errors, camera=args.camera or "still", hold_rests=True) if args.demo else None
    window = MainWindow(args.session, demo=args.demo, rig=rig, replay=args.replay, speed=args.speed)
    for signum in (signal.SIGINT, signal.SIGTERM):         # Ctrl-C or kill: close the session and devices cleanly
        signal.signal(signum, lambda *_: window.quit_without_asking())
    wake = QTimer(interval=200, timeout=lambda: None)      # lets Python run those handlers while Qt waits
    wake.start()
    window.show()
    status = app.exec()
    window.shutdown()
    return status


def _error_model(parser, args):
    """The demo's error model (None: ideal, today's demo); a bad name or file ends the start in one line (exit 2)."""
    if args.errors is None or args.errors == "ideal":
        return None
    if not args.demo:
        parser.error("--errors applies to the demo only; add --demo")
    try:
        return load_error_model(args.errors)
    except ValueError as err:
        parser.error(str(err))


if __name__ == "__main__":
    sys.exit(main())
