"""``snreg session retrack``: track every stored node's window again on the recorded video (wired into
``snreg session`` by :func:`add_retrack_parser`)."""

from __future__ import annotations

import json

from snreg.errors import UserError

METHODS = ("triangulation", "sgbm", "width")
INSERTION_SOURCES = ("auto", "video", "chain")      # as snreg.workflow.retrack.INSERTION_SOURCES


def add_retrack_parser(commands) -> None:
    retrack = commands.add_parser("retrack", help="track every node's store window again on the recorded video, "
                                  "with the session's calibration or another, and store the result as new node "
                                  "versions (the old stay on record)")
    retrack.add_argument("session", help="session file (.h5) recorded with video")
    retrack.add_argument("--calib", help="stereo calibration file to track with (default: the session's own)")
    retrack.add_argument("--probe", help="probe model file (default: the DROP-IN probe)")
    retrack.add_argument("--method", choices=METHODS, default="triangulation", help="tracking method")
    retrack.add_argument("--insertion", choices=INSERTION_SOURCES, default="auto",
                         help="the camera's insertion each fix is mapped with: video (tracked over the recorded "
                         "video from the session chain's distance), chain (the chain's constant distance: a still "
                         "camera), auto (default: video when the session tracked the insertion live, else chain)")
    retrack.add_argument("--dry-run", action="store_true", help="say where each node would move; store nothing")
    retrack.add_argument("--json", action="store_true", help='one JSON object: {"nodes": [{"id", "kind", "before_mm", '
                         '"after_mm", "moved_mm", "before_camera_mm", "after_camera_mm", "before_trocar_camera_mm", '
                         '"after_trocar_camera_mm", "fixes"}], "calibration", "method", "insertion": {"pairs", '
                         '"tracked", "lost"} or null, "stored"}')
    retrack.set_defaults(func=cmd_retrack)


def cmd_retrack(args) -> int:
    from snreg.camera import CalibrationFileError, load_calibration
    from snreg.probe import load_probe_model
    from snreg.session import SessionError
    from snreg.workflow.retrack import retrack, store_retracked
    try:
        calibration = load_calibration(args.calib) if args.calib else None
        probe = load_probe_model(args.probe) if args.probe else None
        result = retrack(args.session, calibration=calibration, probe=probe, method=args.method,
                         insertion=args.insertion)
        followed = "tracked over the video" if result.insertion is not None else "the chain's constant"
        what = f"calibration {args.calib or 'of the session'}, method {args.method}, insertion {followed}" + \
            (f", probe {args.probe}" if args.probe else "")
        stored = 0 if args.dry_run else store_retracked(args.session, result, f"retrack: {what}")
    except (SessionError, CalibrationFileError, ValueError) as err:
        raise UserError(str(err)) from None
    except OSError as err:
        raise UserError(f"{err.filename or args.session}: {err.strerror or err}") from None
    if args.json:
        print(json.dumps({"nodes": [node.to_json() for node in result.nodes], "calibration": args.calib or "session",
                          "stereo_version": result.stereo_version, "method": args.method,
                          "insertion": None if result.insertion is None else result.insertion.to_json(),
                          "stored": stored}))
        return 0
    if result.insertion is not None:
        summary = result.insertion.to_json()
        print(f"camera insertion tracked over the video: {summary['tracked']} of {summary['pairs']} pairs "
              f"({summary['lost']} lost; orientations: {summary['orientation']})")
    for node in result.nodes:
        before = ", ".join(f"{v:.2f}" for v in node.node.xyz_trocar)
        name = node.node.id if node.node.kind == "node" else f"landmark {node.node.id!r}"
        if node.after_trocar is None:
            print(f"{name}: at ({before}) mm, not re-tracked: {node.problem}")
            continue
        after = ", ".join(f"{v:.2f}" for v in node.after_trocar)
        insertion = "" if result.insertion is None else \
            f", camera {_mm(node.node.trocar_camera_mm)} -> {_mm(node.after_insertion_mm)}"
        print(f"{name}: was ({before}) mm, now ({after}) mm: moved {node.moved_mm:.2f} mm "
              f"({node.fixes} fixes in {node.frames} frames{insertion})")
    print("dry run: nothing stored" if args.dry_run else f"{stored} nodes stored as new versions; the old positions "
          "stay on record in the session's events")
    return 0


def _mm(value: float) -> str:
    return f"{value:.1f} mm" if value == value else "untracked"
