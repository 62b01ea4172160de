"""``snreg session info|export|recover``: wired into ``snreg.cli`` by :func:`add_session_parser`."""

from __future__ import annotations

import json
from pathlib import Path

from snreg.cli.common import check_output_file
from snreg.errors import UserError


def add_session_parser(subparsers) -> None:
    """Add ``session`` with its ``info``, ``export``, ``recover``, ``verify`` and ``retrack`` subcommands; each sets
    ``func``."""
    session = subparsers.add_parser("session", help="inspect, export or recover a session file (HDF5)")
    commands = session.add_subparsers(dest="session_command", required=True, metavar="ACTION")
    info = commands.add_parser("info", help="case id, creation time, counts of nodes and stream samples")
    info.add_argument("session", help="session file (.h5)")
    info.add_argument("--json", action="store_true", help="one JSON object on stdout")
    info.set_defaults(func=cmd_info)
    export = commands.add_parser("export", help="write the intraop nodes and landmarks (trocar frame, mm) as CSV or "
                                 "Slicer markups, or the probe pose stream as a 3D Slicer sequence")
    export.add_argument("session", help="session file (.h5)")
    export.add_argument("--format", choices=("csv", "slicer", "slicer-sequence", "calibration"), default="csv",
                        help="csv or slicer: the intraop nodes into the file OUT (node CSV, landmarks as rows of kind "
                        "landmark; 3D Slicer .mrk.json, landmarks in a point list of their own); "
                        "slicer-sequence: the probe poses (trocar frame) as ProbeTipToTrocar.seq.mha, 3D Slicer's "
                        "linear transform sequence, into the folder OUT; calibration: the stereo calibration the "
                        "session used, as a calibration file (.yaml)")
    export.add_argument("-o", "--output", required=True, help="node file, or folder for slicer-sequence")
    export.set_defaults(func=cmd_export)
    recover = commands.add_parser("recover", help="rebuild a clean session file from a damaged one and its journal")
    recover.add_argument("session", help="session file (.h5); its journal SESSION.h5.journal is read too")
    recover.add_argument("-o", "--output", default=None,
                         help="write the recovered session to this new file (default: replace the session file, "
                              "keeping the damaged one beside it)")
    recover.set_defaults(func=cmd_recover)
    check = commands.add_parser("verify", help="read every dataset (Fletcher-32, digests) and video (size, SHA-256) "
                                "and name what is damaged; exit status 1 when anything is")
    check.add_argument("session", help="session file (.h5)")
    check.add_argument("--json", action="store_true", help='one JSON object: {"ok", "damaged": [{"what", "where", '
                       '"why"}], "unproven", "videos"}')
    check.set_defaults(func=cmd_verify)
    from snreg.cli.retrack import add_retrack_parser
    add_retrack_parser(commands)


def cmd_info(args) -> int:
    from snreg.session.export import session_info
    info = _guard(session_info, args.session)
    if args.json:
        print(json.dumps(info))
        return 0
    streams = ", ".join(f"{name} {n}" for name, n in info["streams"].items())
    regs = "; ".join(f"#{r['n']} {r['method']} RMS {r['rms_mm']:.2f} mm" + (" (final)" if r["final"] else "")
                     for r in info["registrations"]) or "none"
    print(f"case {info['case_id'] or '(none)'}, created {info['created_utc'] or '(unknown)'}, "
          f"format {info['format_version']}, snreg {info['snreg_version'] or '(unknown)'}")
    print(f"nodes: {info['intraop_nodes']} intraop, {info['preop_nodes']} preop; streams: {streams}")
    if info["intraop_landmarks"] or info["preop_landmarks"]:
        names = ", ".join(node["id"] for node in info["landmarks"])
        print(f"landmarks: {info['intraop_landmarks']} stored in surgery{f' ({names})' if names else ''}, "
              f"{info['preop_landmarks']} on the CT")
    down = info.get("preop_down")
    print(f"preop down: {down['source'] if down else 'unknown (no patient position stored with the preop nodes)'}")
    camera = info["camera"]
    if camera["tracked"] or camera["lost"] or any(node["trocar_camera_mm"] is not None for node in info["nodes"]):
        mapped = ", ".join(f"{node['id']} " + ("untracked" if node["trocar_camera_mm"] is None else
                                               f"{node['trocar_camera_mm']:.1f} mm") for node in info["nodes"])
        print(f"camera insertion: tracked on {camera['tracked']} pairs, lost on {camera['lost']}; nodes mapped at: "
              f"{mapped or 'none stored'}")
    if any(node["cov_trocar_mm2"] is not None for node in info["nodes"]):
        from snreg.tracking.uncertainty import ellipsoid_radius_mm
        spreads = ", ".join(f"{node['id']} " + ("unknown" if node["cov_trocar_mm2"] is None else
                                                f"{ellipsoid_radius_mm(node['cov_trocar_mm2']):.1f} mm")
                            for node in info["nodes"])
        print(f"node errors, 90 % ellipsoid's longest semi-axis: {spreads}")
    print(f"calibration: {', '.join(info['calibration']) or 'none'}; registrations: {regs}")
    for video in info["videos"]:
        print(f"video {video['side']}: {video['path']} ({video['frames']} frames, {video['codec']})")
    for problem in info["problems"]:
        print(f"damaged: {problem}")
    for damage in info["damage"]:
        print(f"DAMAGED {damage['what']} {damage['where']}: {damage['why']}")
    if info["damaged"]:
        source = ("the journal holds what it recorded (nodes, registrations, calibration), shown above"
                  if info["journal"] else "there is no journal beside it: only what the file still holds is shown")
        print(f"the session file is damaged; {source}; run 'snreg session verify' for details and "
              "'snreg session recover' to write a clean copy")
    return 0


def cmd_export(args) -> int:
    if args.format == "calibration":
        from snreg.session.export import export_calibration
        check_output_file(args.output, "calibration file")
        _guard(export_calibration, args.session, args.output)
        print(f"wrote the session's stereo calibration to {args.output}")
        return 0
    if args.format == "slicer-sequence":
        from snreg.session.slicer_sequence import write_slicer_sequence
        path = _guard(write_slicer_sequence, args.session, args.output)
        print(f"wrote the probe pose sequence (trocar frame, mm) to {path}")
        return 0
    from snreg.session.export import export_nodes
    check_output_file(args.output, "node file")
    points = _guard(export_nodes, args.session, args.format, args.output)
    marks = f" and {len(points.landmarks)} landmarks" if len(points.landmarks) else ""
    print(f"wrote {len(points.nodes)} nodes{marks} to {args.output}")
    return 0


def cmd_verify(args) -> int:
    from snreg.files import require_regular_file
    from snreg.session.integrity import verify
    require_regular_file(args.session, "session", UserError)
    report = verify(args.session)
    if args.json:
        print(json.dumps(report.to_json()))
    else:
        for damage in report.damaged:
            print(f"DAMAGED {damage.what} {damage.where}: {damage.why}")
        for note in report.unproven:
            print(f"not proven: {note}")
        print(f"{args.session}: " + ("every dataset and video passed its check" if report.ok else
                                     f"{len(report.damaged)} damaged; recover what is left with 'snreg session "
                                     "recover' or keep the file for inspection"))
    return 0 if report.ok else 1


def cmd_recover(args) -> int:
    from snreg.session.recovery import recover
    if args.output is not None and Path(args.output).resolve() != Path(args.session).resolve():
        check_output_file(args.output, "recovered session", new=True)
        check_output_file(f"{args.output}.journal", "recovered session", new=True)
    report = _guard(recover, args.session, args.output)
    print("\n".join(report.lines()))
    return 0


def _guard(func, *args):
    """Run ``func``; a session or file error becomes a one-sentence :class:`snreg.errors.UserError`."""
    from snreg.session.schema import SessionError
    try:
        return func(*args)
    except SessionError as err:
        raise UserError(str(err)) from None
    except OSError as err:
        raise UserError(f"{err.filename or args[0]}: {err.strerror or err}") from None
