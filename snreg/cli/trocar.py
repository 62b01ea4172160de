"""``snreg calibrate trocar``: the trocar and IMU constants of the chain (:mod:`snreg.chain`).

``snreg calibrate trocar pivot --images GLOB --board COLSxROWS --square MM --calib calib.yaml [--imu-csv CSV]
[--imu-trocar MM] [-o chain.json]``: pivot calibration (:mod:`snreg.calibration.pivot`) from left images
of a still board taken while the endoscope pivots about the trocar; with an IMU CSV (columns ``yaw``,
``pitch``, ``roll`` in degrees, sensor to earth, one row per image in sorted image order) also the
IMU-camera rotation.

``snreg calibrate trocar tissue --left GLOB --right GLOB --calib calib.yaml [--imu-csv CSV] [--imu-trocar MM]
[--probe P.yaml] [-o chain.json] [--json]``: the same pivot calibration with no board, from stereo pairs of still
tissue taken while the endoscope turns about the trocar (:mod:`snreg.calibration.tissue_pivot`); the IMU CSV as for
``pivot``, one row per pair.

``snreg calibrate trocar manual --imu-trocar MM --trocar-camera MM [-o chain.json]``: the thesis's
hand-measured chain (§4.1: 460 and 158 mm, axes aligned by eye), printed as JSON.

A recording judged bad writes no chain file (exit status 2).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from snreg.cli.common import (check_output_file, finite_float, folder_pairs, positive_float, progress,
                              read_orientations, write_text)
from snreg.errors import UserError

__all__ = ["add_trocar_parser"]

THESIS_IMU_TROCAR_MM = 460.0    # snreg.chain.THESIS_IMU_TROCAR_MM (a test keeps them equal)

MAX_DISTANCE_MM = 5000.0         # an endoscope is well under a metre long


def _distance(text: str) -> float:
    """A distance along the endoscope, mm, at most ``MAX_DISTANCE_MM`` (its sign is the chain's to check)."""
    value = finite_float(text)
    if abs(value) > MAX_DISTANCE_MM:
        raise argparse.ArgumentTypeError(f"expected a distance of at most {MAX_DISTANCE_MM:g} mm, got {text!r}")
    return value


def add_trocar_parser(calibrate_subparsers) -> argparse.ArgumentParser:
    """Add ``trocar`` with its modes ``pivot``, ``tissue`` and ``manual`` to the ``calibrate`` subparsers; returns its
    parser."""
    trocar = calibrate_subparsers.add_parser("trocar", help="trocar and IMU calibration of the chain (thesis §3.5, §4.1)")
    modes = trocar.add_subparsers(dest="trocar_mode", required=True)
    p = modes.add_parser("pivot", help="pivot calibration from images of a still board",
                         description="Find the trocar pivot in the camera frame from left images of a still checkerboard "
                                     "taken while the endoscope pivots about the trocar in two directions.")
    p.add_argument("--images", required=True, nargs="+", metavar="GLOB", help="left images, e.g. 'pivot/left*.png' (quoted)")
    p.add_argument("--board", required=True, metavar="COLSxROWS", help="inner corners as OpenCV counts them, e.g. 10x7")
    p.add_argument("--square", required=True, type=positive_float, metavar="MM", help="square size, mm")
    p.add_argument("--calib", required=True, help="stereo calibration file (.yaml); its left camera is used")
    p.add_argument("--imu-csv", metavar="CSV", help="IMU orientation per image: columns yaw,pitch,roll (degrees), "
                                                    "rows in sorted image order")
    p.add_argument("--imu-trocar", type=_distance, default=THESIS_IMU_TROCAR_MM, metavar="MM",
                   help=f"IMU-trocar distance for the chain file, mm (default {THESIS_IMU_TROCAR_MM:g}, thesis manual; "
                        "it cancels out of the chain)")
    p.add_argument("-o", "--output", metavar="JSON", help="write the chain constants as JSON")
    p.set_defaults(func=cmd_trocar_pivot)
    p = modes.add_parser("tissue", help="pivot calibration from stereo pairs of tissue, no board",
                         description="Find the trocar pivot in the camera frame from stereo pairs of still tissue taken "
                                     "while the endoscope turns about the trocar in two directions without sliding: "
                                     "the camera's own motion from the stereo pairs, fitted to one pivot.")
    p.add_argument("--left", required=True, metavar="GLOB", help="left images (natural name order), e.g. 'turn/left/*.png'")
    p.add_argument("--right", required=True, metavar="GLOB", help="right images, one per left image")
    p.add_argument("--calib", required=True, help="stereo calibration file (.yaml)")
    p.add_argument("--imu-csv", metavar="CSV", help="IMU orientation per pair: columns yaw,pitch,roll (degrees, "
                                                    "earth_from_imu), rows in sorted image order")
    p.add_argument("--imu-trocar", type=_distance, default=THESIS_IMU_TROCAR_MM, metavar="MM",
                   help=f"IMU-trocar distance for the chain file, mm (default {THESIS_IMU_TROCAR_MM:g}; it cancels out "
                        "of the chain)")
    p.add_argument("--probe", help="probe model file, to leave the probe out of the tissue (default: "
                                   "resources/probe/drop_in_probe.yaml)")
    p.add_argument("-o", "--output", metavar="JSON", help="write the chain constants as JSON (method \"tissue\")")
    p.add_argument("--json", action="store_true",
                   help='print one JSON object: {"trocar_camera_mm", "distance_sd_mm", "rms_mm", "tilt_range_deg", '
                        '"pivot_camera_mm", "pairs", "views", "used", "lost", "verdict", "advice", "imu_from_camera" '
                        '({"yaw", "pitch", "roll", "rms_deg", "pairs"} or null), "chain" (the file written or null)}')
    p.set_defaults(func=cmd_trocar_tissue)
    p = modes.add_parser("manual", help="hand-measured distances (thesis §4.1)",
                         description="Chain constants from measured distances, IMU axes aligned with the camera's by eye.")
    p.add_argument("--imu-trocar", required=True, type=_distance, metavar="MM",
                   help="IMU-trocar distance, mm (thesis 460)")
    p.add_argument("--trocar-camera", required=True, type=_distance, metavar="MM",
                   help="trocar-camera distance, mm (thesis 158)")
    p.add_argument("-o", "--output", metavar="JSON", help="also write the chain constants to this file")
    p.set_defaults(func=cmd_trocar_manual)
    return trocar


def cmd_trocar_manual(args) -> int:
    """Print (and with ``-o`` write) the thesis's manual chain as JSON; bad input raises ``UserError``."""
    from snreg.chain import ChainCalibration

    if args.output:
        check_output_file(args.output, "chain file")
    try:
        chain = ChainCalibration.manual(args.imu_trocar, args.trocar_camera)
    except ValueError as err:
        raise UserError(str(err)) from None
    text = _chain_json(chain, "manual")
    if args.output:
        write_text(args.output, text + "\n", "chain file")
    print(text)
    return 0


def cmd_trocar_pivot(args) -> int:
    """Run the pivot calibration on image files and report it; bad input raises ``UserError``, and so does a
    recording judged bad (too little orientation spread, a large residual): then no chain file is written."""
    import numpy as np

    from snreg.calibration.checkerboard import Board, find_corners
    from snreg.calibration.images import expand_globs, read_grey
    from snreg.calibration.pivot import (MIN_POSES, board_from_camera_pose, imu_camera_rotation,
                                         imu_from_camera_transform, pivot_calibration)
    from snreg.camera import CalibrationFileError, load_calibration
    from snreg.chain import ChainCalibration
    from snreg.geometry import euler_from_rotation

    output = check_output_file(args.output, "chain file") if args.output else None
    try:
        board = Board.parse(args.board, args.square)
        calib = load_calibration(args.calib)
        paths = expand_globs(args.images, "image")
        imu = read_orientations(args.imu_csv, len(paths), 'image') if args.imu_csv else None
        found, poses = [], []
        report = progress("pivot: images searched")
        for k, path in enumerate(paths):
            report(k + 1, len(paths))
            image = read_grey(path)
            if (image.shape[1], image.shape[0]) != calib.image_size:
                raise ValueError(f"{path} is {image.shape[1]}x{image.shape[0]} but the calibration is for "
                                 f"{calib.image_size[0]}x{calib.image_size[1]} images")
            corners = find_corners(image, board)
            if corners is not None:
                found.append(k)
                poses.append(board_from_camera_pose(corners, board, calib.K1, calib.D1))
        if len(poses) < MIN_POSES:
            raise ValueError(f"board {board.cols}x{board.rows} (inner corners) found in only {len(poses)} of {len(paths)} "
                             f"images, need {MIN_POSES}; check --board (inner corners) and that the board is in view")
        poses = np.array(poses)
        pivot = pivot_calibration(poses)
        hand_eye = imu_camera_rotation(imu[found][pivot.inliers], poses[pivot.inliers]) if imu is not None else None
        rotation = hand_eye.imu_from_camera if hand_eye is not None else np.eye(3)
        chain = ChainCalibration(imu_from_camera_transform(rotation, pivot, args.imu_trocar), args.imu_trocar)
    except (ValueError, CalibrationFileError) as err:
        raise UserError(str(err)) from None
    lines = _report(pivot, board, paths, found)
    if hand_eye is not None:
        yaw, pitch, roll = euler_from_rotation(hand_eye.imu_from_camera)
        lines.append(f"IMU-camera rotation (imu_from_camera; yaw, pitch, roll): {yaw:.2f}, {pitch:.2f}, {roll:.2f} degrees; "
                     f"RMS residual {hand_eye.rms_deg:.2f} degrees over {hand_eye.n_pairs} pose pairs")
    else:
        lines.append("IMU-camera rotation: identity assumed (no --imu-csv; the thesis aligned the axes by eye)")
    print("\n".join(lines))
    if pivot.verdict == "bad":
        raise UserError(f"pivot calibration refused: {pivot.advice} (orientation spread {pivot.tilt_range_deg:.1f} degrees, "
                        f"residual {pivot.rms_mm:.2f} mm){'; no chain file written' if output else ''}")
    if output is not None:
        write_text(output, _chain_json(chain, "pivot") + "\n", "chain file")
        print(f"wrote {output}")
    return 0


def cmd_trocar_tissue(args) -> int:
    """Follow the camera over the tissue pairs, fit the pivot and report it; bad input raises ``UserError``, and so
    does a recording judged bad: then no chain file is written."""
    import numpy as np

    from snreg.calibration.pivot import MIN_POSES, imu_camera_rotation, imu_from_camera_transform
    from snreg.calibration.tissue_pivot import tissue_pivot_calibration
    from snreg.camera import CalibrationFileError, load_calibration
    from snreg.chain import ChainCalibration
    from snreg.probe import load_probe_model
    from snreg.sources import ImageFolderSource, SourceError
    from snreg.workflow.tissue_capture import follow_tissue

    output = check_output_file(args.output, "chain file") if args.output else None
    try:
        calibration = load_calibration(args.calib)
        probe = load_probe_model(args.probe)
        source = ImageFolderSource(args.left, args.right)
        imu = read_orientations(args.imu_csv, len(source), "pair") if args.imu_csv else None
    except (CalibrationFileError, SourceError, ValueError) as err:
        raise UserError(str(err)) from None

    followed = []
    try:
        for pose in follow_tissue(folder_pairs(source, "tissue: pairs followed"), calibration, probe):
            followed.append(pose)
    except ValueError as err:
        raise UserError(f"pair {len(followed)}: {err}") from None
    tracked = [k for k, pose in enumerate(followed) if pose.tracked]
    if len(tracked) < MIN_POSES:
        reasons = sorted({pose.reason for pose in followed if not pose.tracked})
        raise UserError(f"the camera's pose over the tissue was found in only {len(tracked)} of {len(followed)} pairs, "
                        f"need {MIN_POSES} ({'; '.join(reasons)}); record pairs with textured tissue in view")
    poses = np.array([followed[k].tissue_from_camera for k in tracked])
    try:
        pivot = tissue_pivot_calibration(poses)
        hand_eye = (imu_camera_rotation(imu[tracked][pivot.inliers], poses[pivot.inliers]) if imu is not None
                    else None)
        rotation = hand_eye.imu_from_camera if hand_eye is not None else np.eye(3)
        chain = ChainCalibration(imu_from_camera_transform(rotation, pivot, args.imu_trocar), args.imu_trocar)
    except ValueError as err:
        raise UserError(str(err)) from None
    written = output if output is not None and pivot.verdict != "bad" else None
    if args.json:
        print(json.dumps(_tissue_summary(pivot, hand_eye, followed, tracked, written)))
    else:
        print("\n".join(_tissue_report(pivot, hand_eye, followed, tracked)))
    if pivot.verdict == "bad":
        raise UserError(f"tissue pivot calibration refused: {pivot.advice}{'; no chain file written' if output else ''}")
    if written is not None:
        write_text(written, _chain_json(chain, "tissue") + "\n", "chain file")
        if not args.json:
            print(f"wrote {written}")
    return 0


def _tissue_summary(pivot, hand_eye, followed: list, tracked: list[int], written) -> dict:
    """The ``--json`` object of ``calibrate trocar tissue``."""
    from snreg.geometry import euler_from_rotation

    rotation = None
    if hand_eye is not None:
        yaw, pitch, roll = euler_from_rotation(hand_eye.imu_from_camera)
        rotation = {"yaw": round(yaw, 4), "pitch": round(pitch, 4), "roll": round(roll, 4),
                    "rms_deg": round(hand_eye.rms_deg, 4), "pairs": hand_eye.n_pairs}
    return {"trocar_camera_mm": round(pivot.trocar_camera_mm, 3), "distance_sd_mm": round(pivot.distance_sd_mm, 3),
            "rms_mm": round(pivot.rms_mm, 3), "tilt_range_deg": round(pivot.tilt_range_deg, 2),
            "pivot_camera_mm": [round(float(v), 3) for v in pivot.pivot_camera_mm], "pairs": len(followed),
            "views": len(tracked), "used": pivot.n_used, "lost": len(followed) - len(tracked),
            "verdict": pivot.verdict, "advice": pivot.advice, "imu_from_camera": rotation,
            "chain": None if written is None else str(written)}


def _tissue_report(pivot, hand_eye, followed: list, tracked: list[int]) -> list[str]:
    """The text report of ``calibrate trocar tissue`` (pairs numbered from 0 in sorted image order)."""
    from collections import Counter

    import numpy as np

    from snreg.geometry import euler_from_rotation

    x, y, z = pivot.pivot_camera_mm
    lines = [f"tissue pivot calibration: camera pose found in {len(tracked)} of {len(followed)} pairs"]
    for reason, count in Counter(pose.reason for pose in followed if not pose.tracked).most_common():
        lines.append(f"lost in {count} pair{'s' if count > 1 else ''}: {reason}")
    outliers = [str(tracked[k]) for k in np.flatnonzero(~pivot.inliers)]
    if outliers:
        lines.append(f"views left out as outliers: pairs {', '.join(outliers)}")
    lines += [f"pivot in the camera frame: {x:.2f}, {y:.2f}, {z:.2f} mm",
              f"trocar-camera distance: {pivot.trocar_camera_mm:.2f} mm (standard error {pivot.distance_sd_mm:.2f} mm)",
              f"RMS residual: {pivot.rms_mm:.2f} mm over {pivot.n_used} views; turn range {pivot.tilt_range_deg:.1f} degrees"]
    if hand_eye is not None:
        yaw, pitch, roll = euler_from_rotation(hand_eye.imu_from_camera)
        lines.append(f"IMU-camera rotation (imu_from_camera; yaw, pitch, roll): {yaw:.2f}, {pitch:.2f}, {roll:.2f} degrees; "
                     f"RMS residual {hand_eye.rms_deg:.2f} degrees over {hand_eye.n_pairs} pose pairs")
    else:
        lines.append("IMU-camera rotation: identity assumed (no --imu-csv)")
    lines.append(f"verdict: {pivot.verdict}: {pivot.advice}")
    return lines


def _report(pivot, board, paths: list[str], found: list[int]) -> list[str]:
    """The report lines of a pivot calibration (a ``PivotResult`` on a ``Board``)."""
    import numpy as np

    x, y, z = pivot.pivot_camera_mm
    bx, by, bz = pivot.pivot_board_mm
    lines = [f"pivot calibration from {len(found)} of {len(paths)} images, board {board.cols}x{board.rows} inner corners "
             f"of {board.square_mm:g} mm"]
    missing = [Path(p).name for k, p in enumerate(paths) if k not in found]
    if missing:
        lines.append(f"board not found in (skipped): {', '.join(missing)}")
    outliers = [Path(paths[found[k]]).name for k in np.flatnonzero(~pivot.inliers)]
    if outliers:
        lines.append(f"poses left out as outliers: {', '.join(outliers)}")
    lines += [f"pivot in the camera frame: {x:.2f}, {y:.2f}, {z:.2f} mm",
              f"trocar-camera distance: {pivot.trocar_camera_mm:.2f} mm (standard error {pivot.distance_sd_mm:.2f} mm)",
              f"pivot in the board frame: {bx:.2f}, {by:.2f}, {bz:.2f} mm",
              f"RMS residual: {pivot.rms_mm:.2f} mm over {pivot.n_used} poses; tilt range {pivot.tilt_range_deg:.1f} degrees",
              f"verdict: {pivot.verdict}: {pivot.advice}"]
    return lines


def _chain_json(chain, method: str) -> str:
    """A ``ChainCalibration`` as the chain file's JSON, with the method that made it."""
    return json.dumps({**chain.to_dict(), "method": method})
