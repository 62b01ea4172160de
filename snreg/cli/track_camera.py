"""``snreg track-camera``: the camera's insertion through the trocar over a sequence of stereo pairs (docs/design.md, Contracts).

The pairs are two image globs in natural name order, the IMU's ``earth_from_imu`` one CSV row per pair (``yaw,pitch,
roll`` degrees, as ``calibrate trocar pivot --imu-csv``), the chain the file ``calibrate trocar`` writes, whose
``trocar_camera_mm`` is the insertion at the first pair (at the first pair with tissue in view when the first ones
show none). Each pair is tracked (the distance, a quality, the departure from the pivot model) or lost, never
guessed.
"""

from __future__ import annotations

import json
import sys

from snreg.cli.common import folder_pairs, read_orientations
from snreg.errors import UserError

__all__ = ["add_track_camera_parser", "cmd_track_camera"]


def add_track_camera_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "track-camera", help="the camera's insertion through the trocar over a stereo sequence",
        description="The pivot-to-camera distance per stereo pair, from the tissue seen in both eyes, the IMU's "
                    "orientation and the trocar chain: tracked with a quality, or lost with the reason.")
    p.add_argument("--left", required=True, metavar="GLOB", help="left images (natural name order)")
    p.add_argument("--right", required=True, metavar="GLOB", help="right images, one per left image")
    p.add_argument("--imu-csv", required=True, metavar="CSV",
                   help="the IMU orientation per pair: columns yaw,pitch,roll (degrees, earth_from_imu, ZYX)")
    p.add_argument("--calib", required=True, help="stereo calibration file (.yaml)")
    p.add_argument("--chain", required=True, metavar="CHAIN.json",
                   help="the trocar chain as 'snreg calibrate trocar' writes it; its trocar_camera_mm is the "
                        "insertion at the first pair")
    p.add_argument("--probe", help="probe model file, to leave the probe out of the tissue (default: "
                                   "resources/probe/drop_in_probe.yaml)")
    p.add_argument("--json", action="store_true",
                   help='print one JSON object: {"frames": [{"index", "trocar_camera_mm" (null when lost), "state", '
                        '"quality", "residual_mm", "sd_mm", "reason"}], "tracked", "lost"}')
    p.set_defaults(func=cmd_track_camera)


def cmd_track_camera(args) -> int:
    from snreg.camera import CalibrationFileError, load_calibration
    from snreg.chain import read_chain_file
    from snreg.probe import load_probe_model
    from snreg.sources import ImageFolderSource, SourceError
    from snreg.workflow.insertion import follow_insertion

    try:
        calibration = load_calibration(args.calib)
        chain = read_chain_file(args.chain)
        probe = load_probe_model(args.probe)
        source = ImageFolderSource(args.left, args.right)
        orientations = read_orientations(args.imu_csv, len(source), "pair")
    except (CalibrationFileError, SourceError, ValueError) as err:
        raise UserError(str(err)) from None

    frames = []
    try:
        pairs = folder_pairs(source, "track-camera: pairs")
        for estimate in follow_insertion(pairs, orientations.as_matrix(), calibration, chain, probe):
            frames.append(estimate)
    except ValueError as err:
        raise UserError(f"pair {len(frames)}: {err}") from None
    tracked = sum(f.tracked for f in frames)
    if args.json:
        print(json.dumps({"frames": [f.as_dict() for f in frames], "tracked": tracked,
                          "lost": len(frames) - tracked}))
        return 0
    print(f"{'pair':>5} {'state':8} {'insertion mm':>12} {'quality':>7} {'sd mm':>6} {'residual mm':>11}  reason")
    for f in frames:
        if f.tracked:
            print(f"{f.index:5d} {f.state:8} {f.trocar_camera_mm:12.2f} {f.quality:7.2f} {f.sd_mm:6.2f} "
                  f"{f.residual_mm:11.2f}")
        else:
            print(f"{f.index:5d} {f.state:8} {'-':>12} {'-':>7} {'-':>6} {'-':>11}  {f.reason}")
    print(f"{tracked} of {len(frames)} pairs tracked, {len(frames) - tracked} lost", file=sys.stdout)
    return 0
