"""``snreg demo --headless -o SESSION.h5 [--json]``: wired into ``snreg.cli`` by :func:`add_demo_parser`."""

from __future__ import annotations

import json
from pathlib import Path

from snreg.cli.common import check_output_file, positive_int, seed
from snreg.errors import UserError


def add_demo_parser(subparsers) -> None:
    p = subparsers.add_parser("demo", help="the simulated phantom experiment end to end (no hardware)")
    p.add_argument("--headless", action="store_true", help="no window: record, register and report (required here; "
                   "the window is 'snreg-gui --demo')")
    p.add_argument("-o", "--output", required=True, help="session file to create (.h5); the SPECT is written beside it")
    p.add_argument("--fixes", type=positive_int, default=60, help="valid fixes per stored node (thesis: 60)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the rendered scene and the simulated IMU")
    p.add_argument("--json", action="store_true", help='print one JSON object: {"rms_mm", "pairing", "nodes", ...}')
    p.set_defaults(func=cmd_demo)


def cmd_demo(args) -> int:
    from snreg.demo.headless import DemoError, run_headless, spect_path_for
    from snreg.session import SessionError

    if not args.headless:
        raise UserError("the demo with a window is 'snreg-gui --demo'; add --headless to run it here without one")
    check_output_file(args.output, "session", new=True)
    check_output_file(Path(f"{args.output}.journal"), "session journal", new=True)
    check_output_file(spect_path_for(args.output), "phantom SPECT")
    try:
        run = run_headless(args.output, seed=args.seed, fixes_per_node=args.fixes)
    except (SessionError, DemoError, OSError) as err:
        raise UserError(str(err)) from None
    if args.json:
        print(json.dumps(run.to_json()))
        return 0
    out = run.to_json()
    print(f"stored {len(out['nodes'])} nodes in {out['frames']} frames into {out['session']}; SPECT {out['spect']}")
    for node in out["nodes"]:
        print(f"  {node['id']:<4} {node['label']:<6} -> preop {node['preop'] or 'extra':<4} "
              f"{node['distance_mm']:6.2f} mm  confidence {node['confidence']:.3f}")
    print(f"{out['method']}: RMS after registration {out['rms_mm']:.2f} mm; "
          f"pairing {'matches' if out['pairing_correct'] else 'DOES NOT match'} the phantom's truth")
    return 0
