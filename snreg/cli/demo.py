"""``snreg demo --headless -o SESSION.h5 [--json] [--igtl PORT] [--errors ideal|thesis|FILE] [--camera still|surgery]
[--no-camera-tracking]``: wired into ``snreg.cli`` by :func:`add_demo_parser`.

With ``--igtl`` the run serves the live link to 3D Slicer (docs/design.md, Contracts) and waits up to 30 s for the first
client before it starts. docs/design.md (Live link) says "waiting up to 30 s ... before starting", so the run starts anyway after
that (one line on stderr says no client came); a client that connects later still gets the node lists at once.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from snreg.cli.common import check_output_file, int_range, seed
from snreg.errors import UserError

CLIENT_WAIT_S = 30.0
MAX_FIXES = 1000              # ~30 s of video per node


def add_demo_parser(subparsers) -> None:
    p = subparsers.add_parser("demo", help="the simulated phantom experiment end to end (no hardware)")
    p.add_argument("--headless", action="store_true", help="no window: record, register and report (required here; "
                   "the window is 'snreg-gui --demo')")
    p.add_argument("-o", "--output", required=True, help="session file to create (.h5); the SPECT is written beside it")
    p.add_argument("--fixes", type=int_range(1, MAX_FIXES), default=60,
                   help="valid fixes per stored node (thesis: 60)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the rendered scene and the simulated IMU")
    p.add_argument("--json", action="store_true", help='print one JSON object: {"rms_mm", "pairing", "nodes", ...}')
    p.add_argument("--igtl", type=int_range(0, 65535), metavar="PORT", default=None,
                   help="serve the live link to 3D Slicer (OpenIGTLink) on this port of localhost; waits up to "
                   f"{CLIENT_WAIT_S:.0f} s for the first client before starting")
    p.add_argument("--errors", default="ideal", metavar="ideal|thesis|FILE",
                   help="the error model the rig runs with (default ideal: nothing errs but the render's noise; thesis: "
                        "the thesis' phantom set-up, resources/errors/thesis.yaml; or a YAML file like it)")
    p.add_argument("--camera", choices=("still", "surgery"), default="still",
                   help="still: the thesis' phantom, the camera never moves (default); surgery: the camera slides "
                        "through the trocar (+-30 mm) and turns about the pivot (up to 18 deg) between nodes")
    p.add_argument("--no-camera-tracking", action="store_true",
                   help="with --camera surgery: do not follow the camera's insertion; every node is mapped at the "
                        "trocar calibration's distance (to compare)")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args) -> int:
    from snreg.demo.headless import DemoError, run_headless, spect_path_for
    from snreg.registration.wording import check_words, confidence_text
    from snreg.session import SessionError

    if not args.headless:
        raise UserError("the demo with a window is 'snreg-gui --demo'; add --headless to run it here without one")
    if args.no_camera_tracking and args.camera != "surgery":
        raise UserError("--no-camera-tracking applies to --camera surgery: a still camera's insertion is not tracked")
    errors = _error_model(args.errors)
    check_output_file(args.output, "session", new=True)
    check_output_file(Path(f"{args.output}.journal"), "session journal", new=True)
    check_output_file(spect_path_for(args.output), "phantom SPECT")
    link = _serve(args.igtl) if args.igtl is not None else None
    try:
        run = run_headless(args.output, seed=args.seed, fixes_per_node=args.fixes, link=link, errors=errors,
                           camera=args.camera, camera_tracking=not args.no_camera_tracking)
    except (SessionError, DemoError, OSError) as err:
        raise UserError(str(err)) from None
    finally:
        if link is not None:
            link.close(flush_timeout_s=2.0)
    out = run.to_json()
    out["errors"] = args.errors
    if link is not None:
        out["live_link"] = {"address": link.address, "seconds_in_calls": round(run.link_s, 4), "calls": run.link_calls,
                            **vars(link.stats())}
    if args.json:
        print(json.dumps(out))
        return 0
    print(f"stored {len(out['nodes'])} nodes in {out['frames']} frames into {out['session']}; SPECT {out['spect']}")
    for node in out["nodes"]:
        off = math.dist(node["xyz_trocar"], node["truth_trocar"])
        check = check_words(node["confidence"])
        print(f"  {node['id']:<4} {node['label']:<6} -> preop {node['preop'] or 'none':<4} "
              f"{node['distance_mm']:6.2f} mm  confidence {confidence_text(node['confidence'])}  "
              f"({off:.2f} mm from the truth)" + (f"  {check}" if check else ""))
    if out["camera"] == "surgery":
        print(f"the camera slid and turned between nodes; its insertion was "
              f"{'tracked' if out['camera_tracking'] else 'NOT tracked (each node mapped at the calibrated distance)'}")
    print(f"{out['method']}: RMS after registration {out['rms_mm']:.2f} mm; "
          f"pairing {'matches' if out['pairing_correct'] else 'DOES NOT match'} the phantom's truth")
    print(f"{out['used']['words']}\n(the same registration again: {out['repeat']})")
    return 0


def _serve(port: int):
    """Start the live link on ``port`` and wait for the first client (saying so on stderr)."""
    from snreg.errors import LiveLinkError
    from snreg.workflow.live_link import LiveLink

    try:
        link = LiveLink(port)
    except LiveLinkError as err:
        raise UserError(str(err)) from None
    print(f"snreg: serving OpenIGTLink on {link.address}; waiting up to {CLIENT_WAIT_S:.0f} s for a client "
          f"(3D Slicer: OpenIGTLinkIF, type client, host localhost, port {link.port})", file=sys.stderr, flush=True)
    if link.wait_for_client(CLIENT_WAIT_S):
        print("snreg: a client is connected; starting the demo", file=sys.stderr, flush=True)
    else:
        print(f"snreg: no OpenIGTLink client connected within {CLIENT_WAIT_S:.0f} s; running the demo anyway, still "
              f"serving on {link.address}", file=sys.stderr, flush=True)
    return link


def _error_model(name: str):
    """None for the ideal model (today's demo, exactly), else the loaded model; UserError in one line when bad."""
    if name == "ideal":
        return None
    from snreg.demo.errors import load_error_model

    try:
        return load_error_model(name)
    except ValueError as err:
        raise UserError(str(err)) from None
