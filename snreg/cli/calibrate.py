"""``snreg calibrate stereo|import|check``: make, import and check the stereo calibration file (docs/design.md, Contracts).

- ``stereo --left GLOB --right GLOB --board COLSxROWS --square MM -o calib.yaml [--drop 3,7]`` (COLSxROWS: inner
  corners, as OpenCV counts them): prints the RMS figures, the reconstruction error, the baseline, a per-view
  table whose indices ``--drop`` takes and the check on its own views; warns about near-identical views and a
  provisional calibration; writes the calibration file.
- ``import SRC... (--image-size WxH | --frame IMAGE) -o calib.yaml``: another tool's calibration
  (:mod:`snreg.camera.formats`) as snreg's file, its rectification computed when absent.
- ``check calib.yaml --left IMG_OR_GLOB --right IMG_OR_GLOB --board COLSxROWS --square MM [--json]``: fresh board
  views through a calibration (:mod:`snreg.calibration.check`): epipolar and reconstruction errors and a verdict.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from snreg.cli.common import check_output_file, image_size, positive_float, progress
from snreg.errors import UserError

__all__ = ["add_calibrate_parser"]


def add_calibrate_parser(subparsers) -> argparse._SubParsersAction:
    """Add ``calibrate`` (with ``stereo``, ``import`` and ``check``) to the ``snreg`` subparsers; returns its own
    subparsers (``trocar`` joins them)."""
    calibrate = subparsers.add_parser("calibrate", help="camera and trocar calibration")
    commands = calibrate.add_subparsers(dest="calibrate_command", required=True, metavar="WHAT")
    p = commands.add_parser("stereo", help="stereo checkerboard calibration (thesis §4.2)",
                            description="Calibrate a stereo camera from checkerboard image pairs, paired by sorted file name.")
    _board_arguments(p, "GLOB", "images, e.g. 'calib/left*.png' (quoted)")
    p.add_argument("-o", "--output", required=True, help="calibration file to write (.yaml)")
    p.add_argument("--drop", default="", metavar="I,J", help="view indices (from the table) to leave out, e.g. 3,7")
    p.set_defaults(func=cmd_calibrate_stereo)

    p = commands.add_parser("import", help="another tool's stereo calibration as snreg's file",
                            description="Read a stereo calibration made by OpenCV's stereo_calib sample (intrinsics.yml "
                                        "M1 D1 M2 D2 + extrinsics.yml R T [R1 R2 P1 P2 Q]), a file of snreg keys without "
                                        "rectification, or a NifTK/scikit-surgery folder (calib.left.intrinsic(s), "
                                        "calib.*.distortion, calib.r2l.rotation + calib.r2l.translation or calib.l2r); "
                                        "T is taken in mm as given; the rectification is computed when absent.")
    p.add_argument("sources", nargs="+", metavar="SRC", help="the calibration files, or the folder holding them")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--image-size", type=image_size, metavar="WxH", help="image size the calibration was made at")
    size.add_argument("--frame", metavar="IMAGE", help="read the image size from a frame of the camera")
    p.add_argument("-o", "--output", required=True, help="calibration file to write (.yaml)")
    p.set_defaults(func=cmd_calibrate_import)

    p = commands.add_parser("check", help="check a calibration on board views (epipolar and reconstruction errors)",
                            description="Board views through a calibration: the vertical disparity of matched corners "
                                        "after rectification (epipolar error, px), neighbouring-corner distances against "
                                        "the square (reconstruction error, mm) and a verdict good/check/bad with reasons.")
    p.add_argument("calibration", help="calibration file (.yaml)")
    _board_arguments(p, "IMG_OR_GLOB", "image(s) or glob pattern(s)")
    p.add_argument("--json", action="store_true",
                   help='print one JSON object: {"epipolar_rms_px", "reconstruction_mm", "views", "verdict", "reasons", ...}')
    p.set_defaults(func=cmd_calibrate_check)
    return commands


def _board_arguments(p: argparse.ArgumentParser, metavar: str, what: str) -> None:
    p.add_argument("--left", required=True, nargs="+", metavar=metavar, help=f"left {what}")
    p.add_argument("--right", required=True, nargs="+", metavar=metavar, help=f"right {what}, paired by sorted name")
    p.add_argument("--board", required=True, metavar="COLSxROWS",
                   help="inner corners as OpenCV counts them, e.g. 10x7 for a board of 11 x 8 squares")
    p.add_argument("--square", required=True, type=positive_float, metavar="MM", help="square size, mm")


def cmd_calibrate_stereo(args) -> int:
    """Run ``snreg calibrate stereo``; bad input raises ``snreg.errors.UserError`` with one sentence."""
    from snreg.calibration.checkerboard import Board
    from snreg.calibration.stereo import calibrate_stereo, drop_views, load_image_pairs
    from snreg.camera import save_calibration

    try:
        drop = [int(v) for v in args.drop.split(",") if v.strip()]
    except ValueError:
        raise UserError(f"--drop {args.drop!r}: expected comma-separated view indices, e.g. 3,7") from None
    output = check_output_file(args.output, "calibration file")
    try:
        board = Board.parse(args.board, args.square)
        pairs = load_image_pairs(args.left, args.right)
        if sys.stderr.isatty():
            print(f"calibrating from {len(pairs.left)} pairs (seconds to minutes) ...", file=sys.stderr, flush=True)
        result = calibrate_stereo(pairs.left, pairs.right, board, left_names=pairs.left_paths, right_names=pairs.right_paths)
        if drop:
            result = drop_views(result, drop)
    except ValueError as err:
        raise UserError(str(err)) from None
    try:
        save_calibration(result.calibration, output)
    except OSError as err:
        raise UserError(f"{output}: cannot write the calibration file ({err.strerror or err}); nothing was written") from None
    print(_stereo_report(result, pairs.left_paths, pairs.right_paths))
    for warning in result.warnings():
        print(f"snreg: warning: {warning}", file=sys.stderr)
    print(f"wrote {output}")
    return 0


def cmd_calibrate_import(args) -> int:
    """Run ``snreg calibrate import``: another tool's calibration into snreg's file."""
    from snreg.camera import CalibrationFileError, import_calibration, save_calibration

    output = check_output_file(args.output, "calibration file")
    size = args.image_size if args.frame is None else _frame_size(args.frame)
    try:
        imported = import_calibration(args.sources, size)
    except CalibrationFileError as err:
        raise UserError(str(err)) from None
    calib = imported.calibration
    try:
        save_calibration(calib, output)
    except OSError as err:
        raise UserError(f"{output}: cannot write the calibration file ({err.strerror or err}); nothing was written") from None
    rectification = "computed (cv2.stereoRectify, zero disparity)" if imported.rectification_computed else "as given"
    print(f"imported {imported.layout}: images {calib.image_size[0]}x{calib.image_size[1]}, focal length (px) left "
          f"{calib.K1[0, 0]:.1f} {calib.K1[1, 1]:.1f}, right {calib.K2[0, 0]:.1f} {calib.K2[1, 1]:.1f}, baseline "
          f"{calib.baseline_mm:.3f} (units of T, taken as mm); rectification {rectification}")
    print(f"wrote {output}")
    return 0


def cmd_calibrate_check(args) -> int:
    """Run ``snreg calibrate check``: board views through a calibration, the verdict on stdout (exit 0 whatever it is)."""
    from snreg.calibration.check import check_images
    from snreg.calibration.checkerboard import Board
    from snreg.calibration.stereo import load_image_pairs
    from snreg.camera import CalibrationFileError, load_calibration

    try:
        calib = load_calibration(args.calibration)
        board = Board.parse(args.board, args.square)
        pairs = load_image_pairs(args.left, args.right)
        names = [f"{Path(a).name}/{Path(b).name}" for a, b in zip(pairs.left_paths, pairs.right_paths)]
        check = check_images(calib, pairs.left, pairs.right, board, names, progress=progress("check: pairs searched"))
    except (ValueError, CalibrationFileError) as err:
        raise UserError(str(err)) from None
    if args.json:
        print(json.dumps(check.as_json()))
        return 0
    lines = [f"calibration {args.calibration} on {check.views} board view(s) of {board.cols}x{board.rows} inner corners "
             f"of {board.square_mm:g} mm", f"verdict: {check.verdict}"]
    lines += [f"  {reason}" for reason in check.reasons]
    if check.skipped:
        lines.append(f"board not found in (skipped): {', '.join(check.skipped)}")
    lines.append(f"{'view':<36} {'epipolar px':>11} {'recon mm':>9}")
    used = [n for n in names if not any(s.startswith(n + " (") for s in check.skipped)]
    for name, epi, recon in zip(used, check.view_epipolar_px, check.view_reconstruction_mm):
        lines.append(f"{name:<36} {epi:>11.3f} {recon:>9.3f}")
    print("\n".join(lines))
    return 0


def _frame_size(path: str) -> tuple[int, int]:
    """(width, height) of an image file."""
    import cv2

    from snreg.files import require_regular_file

    require_regular_file(path, "--frame image", UserError)
    try:
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    except cv2.error:                  # a header claiming more pixels than OpenCV's limit
        image = None
    if image is None:
        raise UserError(f"{path}: not a readable image; give --frame an image from the calibrated camera, or --image-size WxH")
    return int(image.shape[1]), int(image.shape[0])


def _stereo_report(result, left_paths: list[str], right_paths: list[str]) -> str:
    """The report of a ``StereoResult``: figures, its check on its own views, and the per-view table."""
    calib, board = result.calibration, result.board
    lines = [f"stereo calibration from {result.n_views} views ({result.distinct_views} distinct), board "
             f"{board.cols}x{board.rows} inner corners of {board.square_mm:g} mm, images {calib.image_size[0]}x{calib.image_size[1]}"]
    if result.skipped:
        lines.append(f"board not found in (skipped): {', '.join(Path(p).name for p in result.skipped)}")
    lines += [f"RMS reprojection: stereo {result.rms_px:.3f} px, left {result.eye_rms_px[0]:.3f} px, "
              f"right {result.eye_rms_px[1]:.3f} px (each eye alone: {result.mono_rms_px[0]:.3f}, {result.mono_rms_px[1]:.3f} px)",
              f"reconstruction error: {result.reconstruction_error_mm:.3f} mm (mean |triangulated square side - "
              f"{board.square_mm:g} mm|)",
              f"check on its own views: {result.check.summary()}",
              f"baseline: {calib.baseline_mm:.3f} mm = {calib.baseline_mm / board.square_mm:.3f} squares",
              f"focal length (px): left {calib.K1[0, 0]:.1f} {calib.K1[1, 1]:.1f}, right {calib.K2[0, 0]:.1f} {calib.K2[1, 1]:.1f}",
              "",
              f"{'view':>4}  {'left':<24} {'right':<24} {'left px':>8} {'right px':>8} {'recon mm':>9}"]
    suspect = result.suspect_views
    repeats = dict(result.repeated_views)
    for k, view in enumerate(result.view_ids):
        mark = "  <- check; --drop to leave out" if suspect[k] else ""
        if int(view) in repeats:
            mark += f"  <- repeats view {repeats[int(view)]}"
        lines.append(f"{view:>4}  {Path(left_paths[view]).name:<24} {Path(right_paths[view]).name:<24} "
                     f"{result.view_errors_px[k, 0]:>8.3f} {result.view_errors_px[k, 1]:>8.3f} "
                     f"{result.view_reconstruction_mm[k]:>9.3f}{mark}")
    return "\n".join(lines)
