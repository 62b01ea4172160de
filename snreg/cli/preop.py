"""``snreg preop SPECT_PATH -o nodes.csv [--threshold REL] [--nodes N] [--stations CSV] [--resolution MM]``.

Loads a SPECT (NM) volume -- a multi-frame file, a series directory or slice files -- segments
its nodes (:mod:`snreg.preop.segment`) and writes them as a node file (CSV, or Slicer markups
for ``.mrk.json``) in LPS mm; the CSV carries each centre's covariance (``cov_*`` columns, mm^2), which
``snreg register`` weighs the hot spots by. Nothing from the patient module (name, ID, birth date) is
ever printed or written.

It also says where down is in the nodes' frame on the operating table (:mod:`snreg.preop.gravity`: the SPECT's
Patient Position turned by the table's head-down tilt, ``--tilt``, default 30 degrees) and records what that comes
from in the CSV's comments (``# patient_position: HFS``, ``# table_tilt_deg: 30 (default)``), from which ``snreg
register`` starts. A SPECT whose position gives no down is not refused here (its nodes are still good): the comment
says ``none`` or the position, and ``snreg register`` then asks for the down or an initial alignment.
"""

from __future__ import annotations

import argparse
import sys

from snreg.cli.common import check_output_file, finite_float, float_range, positive_int
from snreg.errors import UserError

__all__ = ["add_preop_parser", "cmd_preop"]

NODE_FILE_SUFFIXES = (".csv", ".mrk.json", ".json")
RESOLUTION_MM = 12.0      # snreg.preop.segment.RESOLUTION_MM, stated here so that building the parser imports no numpy
TABLE_TILT_DEG, MAX_TILT_DEG = 30.0, 60.0     # snreg.preop.gravity's, for the same reason


def add_preop_parser(subparsers) -> argparse.ArgumentParser:
    """Add ``preop`` to the ``snreg`` subparsers; returns its parser."""
    p = subparsers.add_parser("preop", help="sentinel-node centres from a SPECT (NM) DICOM volume",
                              description="Segment the nodes of a SPECT volume by a threshold relative to its "
                                          "maximum, split merged hot spots, and write their centres (LPS mm).")
    p.add_argument("spect", nargs="+", metavar="SPECT_PATH",
                   help="a multi-frame NM file, a directory holding one series, or the slice files")
    p.add_argument("-o", "--output", required=True, metavar="NODES", help="node file to write (.csv or .mrk.json)")
    p.add_argument("--threshold", type=finite_float, default=0.3, metavar="REL",
                   help="activity threshold as a fraction of the maximum, between 0 and 1")
    p.add_argument("--nodes", type=positive_int, metavar="N",
                   help="expected number of nodes (default: every hot spot and peak found)")
    p.add_argument("--stations", metavar="CSV", help="station per node id: a CSV with columns id,station; the nodes are P1, P2, ... hottest first")
    p.add_argument("--resolution", type=finite_float, default=RESOLUTION_MM, metavar="MM",
                   help="the scanner's resolution, FWHM of a point source, for each centre's covariance "
                        f"(default {RESOLUTION_MM:g})")
    p.add_argument("--midline-x", type=finite_float, metavar="MM",
                   help="patient x of the midline for left/right labels (default: the volume centre)")
    p.add_argument("--tilt", type=float_range(0.0, MAX_TILT_DEG, "degrees", low_open=False), metavar="DEG",
                   help="the operating table's head-down tilt (Trendelenburg) that turns the SPECT's down "
                        f"(default: {TABLE_TILT_DEG:g}, the steep Trendelenburg of robotic prostatectomy)")
    p.set_defaults(func=cmd_preop)
    return p


def cmd_preop(args) -> int:
    """Run ``snreg preop``; bad input raises ``snreg.errors.UserError`` with one sentence."""
    import numpy as np

    from snreg.nodes import write_nodes
    from snreg.preop.gravity import volume_down
    from snreg.preop.segment import read_station_table, segment_nodes
    from snreg.preop.volume import PreopError, load_volume

    if not args.output.lower().endswith(NODE_FILE_SUFFIXES):
        raise UserError(f"{args.output}: a node file is written as .csv or .mrk.json; give one of those names")
    check_output_file(args.output, "node file")
    source = args.spect[0] if len(args.spect) == 1 else args.spect
    try:
        stations = read_station_table(args.stations) if args.stations else None
        volume = load_volume(source, modality="NM")
        result = segment_nodes(volume, threshold=args.threshold, n_nodes=args.nodes,
                               midline_x=args.midline_x, stations=stations, resolution_mm=args.resolution)
    except PreopError as err:
        raise UserError(str(err)) from None
    for warning in volume.warnings:
        print(f"snreg: warning: {warning}", file=sys.stderr)
    nodes, down = result.nodes, volume_down(volume, args.tilt)
    if volume.placed_by_default:
        nodes.comments.append("placed by default: positions are relative to the volume, not to the patient")
    nodes.comments.extend(down.comments())
    try:
        write_nodes(nodes, args.output)
    except OSError as err:
        raise UserError(f"{args.output}: cannot write the node file ({err.strerror or err}); nothing was written") from None
    z, y, x = volume.voxels.shape
    sx, sy, sz = volume.spacing_mm
    print(f"{len(nodes)} node(s) above {args.threshold:g} x maximum in a {x}x{y}x{z} volume "
          f"({sx:.3f} x {sy:.3f} x {sz:.3f} mm), written to {args.output}")
    print(_down_text(down, args.output))
    print(f"{'id':<5} {'label':<8} {'x mm':>8} {'y mm':>8} {'z mm':>8} {'peak':>10} {'total':>12} {'sd mm':>6}")
    for k in range(len(nodes)):
        px, py, pz = nodes.xyz[k]
        sd = np.sqrt(np.linalg.eigvalsh(nodes.cov[k]).max())          # along the centre's least certain axis
        print(f"{nodes.ids[k]:<5} {nodes.labels[k]:<8} {px:8.1f} {py:8.1f} {pz:8.1f} "
              f"{result.peak_counts[k]:10.4g} {result.total_counts[k]:12.6g} {sd:6.2f}")
    return 0


def _down_text(down, output: str) -> str:
    """One line: the down in the nodes' frame and what it comes from, or why there is none and what to do."""
    if down.problem:
        return (f"down: unknown: {down.problem}; snreg register will need --down-preop X,Y,Z (LPS) or --initial")
    kept = "" if output.lower().endswith(".csv") else \
        f" (not kept in {output}: give it to snreg register with --down-preop, or write a .csv)"
    x, y, z = down.vector
    return f"down: {x:.3f}, {y:.3f}, {z:.3f} (LPS), {down.source}{kept}"
