"""``snreg calibrate stereo``: checkerboard stereo calibration from two sets of image files.

``snreg calibrate stereo --left GLOB --right GLOB --board COLSxROWS --square MM -o calib.yaml [--drop 3,7]``
(COLSxROWS: inner corners, as OpenCV counts them). Prints the RMS figures, the reconstruction
error, the baseline and a per-view table whose indices ``--drop`` takes; writes the calibration file.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2

from snreg.calibration.checkerboard import Board
from snreg.calibration.stereo import StereoResult, calibrate_stereo, drop_views, load_image_pairs
from snreg.camera import save_calibration
from snreg.errors import UserError

__all__ = ["add_calibrate_parser"]

def add_calibrate_parser(subparsers) -> argparse._SubParsersAction:
    """Add ``calibrate`` (with ``stereo``) to the ``snreg`` subparsers; returns its own subparsers."""
    calibrate = subparsers.add_parser("calibrate", help="camera calibration")
    commands = calibrate.add_subparsers(dest="calibrate_command", required=True)
    p = commands.add_parser("stereo", help="stereo checkerboard calibration (thesis §4.2)",
                            description="Calibrate a stereo camera from checkerboard image pairs, paired by sorted file name.")
    p.add_argument("--left", required=True, nargs="+", metavar="GLOB", help="left images, e.g. 'calib/left*.png' (quoted)")
    p.add_argument("--right", required=True, nargs="+", metavar="GLOB", help="right images, e.g. 'calib/right*.png'")
    p.add_argument("--board", required=True, metavar="COLSxROWS",
                   help="inner corners as OpenCV counts them, e.g. 10x7 for a board of 11 x 8 squares")
    p.add_argument("--square", required=True, type=float, metavar="MM", help="square size, mm")
    p.add_argument("-o", "--output", required=True, help="calibration file to write (.yaml)")
    p.add_argument("--drop", default="", metavar="I,J", help="view indices (from the table) to leave out, e.g. 3,7")
    p.set_defaults(func=cmd_calibrate_stereo)
    return commands


def cmd_calibrate_stereo(args) -> int:
    """Run ``snreg calibrate stereo``; bad input raises ``snreg.errors.UserError`` with one sentence."""

    try:
        drop = [int(v) for v in args.drop.split(",") if v.strip()]
    except ValueError:
        raise UserError(f"--drop {args.drop!r}: expected comma-separated view indices, e.g. 3,7") from None
    output = Path(args.output)
    if not output.parent.is_dir():
        raise UserError(f"{output}: the folder {output.parent} does not exist")
    try:
        board = Board.parse(args.board, args.square)
        pairs = load_image_pairs(args.left, args.right)
        result = calibrate_stereo(pairs.left, pairs.right, board, left_names=pairs.left_paths, right_names=pairs.right_paths)
        if drop:
            result = drop_views(result, drop)
    except ValueError as err:
        raise UserError(str(err)) from None
    try:
        save_calibration(result.calibration, output)
    except cv2.error:
        raise UserError(f"{output}: cannot write the calibration file there") from None
    print(_report(result, pairs.left_paths, pairs.right_paths))
    print(f"wrote {output}")
    return 0


def _report(result: StereoResult, left_paths: list[str], right_paths: list[str]) -> str:
    calib, board = result.calibration, result.board
    lines = [f"stereo calibration from {result.n_views} views, board {board.cols}x{board.rows} inner corners of "
             f"{board.square_mm:g} mm, images {calib.image_size[0]}x{calib.image_size[1]}"]
    if result.skipped:
        lines.append(f"board not found in (skipped): {', '.join(Path(p).name for p in result.skipped)}")
    lines += [f"RMS reprojection: stereo {result.rms_px:.3f} px, left {result.eye_rms_px[0]:.3f} px, "
              f"right {result.eye_rms_px[1]:.3f} px (each eye alone: {result.mono_rms_px[0]:.3f}, {result.mono_rms_px[1]:.3f} px)",
              f"reconstruction error: {result.reconstruction_error_mm:.3f} mm (mean |triangulated square side - "
              f"{board.square_mm:g} mm|)",
              f"baseline: {calib.baseline_mm:.3f} mm = {calib.baseline_mm / board.square_mm:.3f} squares",
              f"focal length (px): left {calib.K1[0, 0]:.1f} {calib.K1[1, 1]:.1f}, right {calib.K2[0, 0]:.1f} {calib.K2[1, 1]:.1f}",
              "",
              f"{'view':>4}  {'left':<24} {'right':<24} {'left px':>8} {'right px':>8} {'recon mm':>9}"]
    suspect = result.suspect_views
    for k, view in enumerate(result.view_ids):
        mark = "  <- check; --drop to leave out" if suspect[k] else ""
        lines.append(f"{view:>4}  {Path(left_paths[view]).name:<24} {Path(right_paths[view]).name:<24} "
                     f"{result.view_errors_px[k, 0]:>8.3f} {result.view_errors_px[k, 1]:>8.3f} "
                     f"{result.view_reconstruction_mm[k]:>9.3f}{mark}")
    return "\n".join(lines)
