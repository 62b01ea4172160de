"""``snreg track LEFT RIGHT --calib calib.yaml``: the probe tip and stripe-band centre from one stereo pair."""

from __future__ import annotations

import json

import cv2

from snreg.camera import load_calibration
from snreg.errors import CalibrationFileError, TrackingError, UserError
from snreg.probe import load_probe_model
from snreg.tracking import StereoTracker

__all__ = ["add_track_parser", "cmd_track"]


def add_track_parser(subparsers) -> None:
    p = subparsers.add_parser("track", help="probe position from one stereo pair")
    p.add_argument("left")
    p.add_argument("right")
    p.add_argument("--calib", required=True, help="stereo calibration file (.yaml)")
    p.add_argument("--probe", help="probe model file (default: resources/probe/drop_in_probe.yaml)")
    p.add_argument("--method", choices=("triangulation", "sgbm", "width"), default="triangulation")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_track)


def cmd_track(args) -> int:
    try:
        calibration = load_calibration(args.calib)
        probe = load_probe_model(args.probe)
    except (CalibrationFileError, ValueError) as err:
        raise UserError(str(err)) from None
    images = []
    for path in (args.left, args.right):
        image = cv2.imread(path, cv2.IMREAD_COLOR)
        if image is None:
            raise UserError(f"{path}: not a readable image")
        images.append(image)
    tracker = StereoTracker(calibration, probe, method=args.method)
    try:
        fix = tracker.marker_width(images[0]) if args.method == "width" else tracker.track(*images)
    except TrackingError as err:
        raise UserError(f"{err}") from None
    doc = fix.as_dict()
    if args.json:
        print(json.dumps(doc))
    else:
        print(f"tip    {fix.tip[0]:8.2f} {fix.tip[1]:8.2f} {fix.tip[2]:8.2f} mm (camera frame)")
        print(f"centre {fix.centre[0]:8.2f} {fix.centre[1]:8.2f} {fix.centre[2]:8.2f} mm")
        print(f"axis   {fix.axis[0]:8.4f} {fix.axis[1]:8.4f} {fix.axis[2]:8.4f}")
        print(f"quality {fix.quality:.3f} ({fix.n_stripes} stripes, {fix.method})")
    return 0
