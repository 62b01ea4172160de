"""``snreg track LEFT RIGHT --calib calib.yaml``: the probe tip and stripe-band centre from one stereo pair.

A pair in which nothing agrees with the probe model (stripe spacing, width, band diameter, working depth
range) has no fix: one line on stderr saying why, exit status 2.
"""

from __future__ import annotations

import json

from snreg.cli.common import depth_range
from snreg.errors import UserError

__all__ = ["add_track_parser", "cmd_track", "DEFAULT_DEPTH_RANGE_MM"]

DEFAULT_DEPTH_RANGE_MM = (20.0, 300.0)   # the default probe model's working_range_mm (a test keeps them equal)


def add_track_parser(subparsers) -> None:
    p = subparsers.add_parser("track", help="probe position from one stereo pair",
                              description="The probe tip and stripe-band centre (mm, left camera frame) from one "
                                          "stereo pair; no fix when nothing in view agrees with the probe model.")
    p.add_argument("left", help="left image")
    p.add_argument("right", help="right image (ignored by --method width)")
    p.add_argument("--calib", required=True, help="stereo calibration file (.yaml)")
    p.add_argument("--probe", help="probe model file (default: resources/probe/drop_in_probe.yaml)")
    p.add_argument("--method", choices=("triangulation", "sgbm", "width"), default="triangulation",
                   help="stripe triangulation, the thesis' SGBM, or the monocular marker-width baseline")
    p.add_argument("--depth-range", type=depth_range, metavar="MIN,MAX",
                   help=f"working depth range, mm from the camera: it bounds the stereo search (disparities) and fixes "
                        f"outside it are refused (default: the probe model's, {DEFAULT_DEPTH_RANGE_MM[0]:g},"
                        f"{DEFAULT_DEPTH_RANGE_MM[1]:g} for the default probe)")
    p.add_argument("--json", action="store_true",
                   help='print one JSON object: {"tip", "centre", "axis", "quality", "method", "n_stripes"}')
    p.set_defaults(func=cmd_track)


def cmd_track(args) -> int:
    from snreg.camera import CalibrationFileError, load_calibration
    from snreg.files import read_image
    from snreg.probe import load_probe_model
    from snreg.tracking import StereoTracker, TrackingError

    try:
        calibration = load_calibration(args.calib)
        probe = load_probe_model(args.probe)
    except (CalibrationFileError, ValueError) as err:
        raise UserError(str(err)) from None
    images = [read_image(path, error=UserError) for path in (args.left, args.right)]
    try:
        tracker = StereoTracker(calibration, probe, method=args.method, depth_range_mm=args.depth_range)
        fix = tracker.track(*images)
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
