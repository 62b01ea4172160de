"""``snreg register PREOP.csv INTRAOP.(csv|h5)``: register the preop nodes to the intraop nodes and pair them."""

from __future__ import annotations

import json
from pathlib import Path

from snreg.cli.common import read_initial
from snreg.errors import NodeFileError, UserError
from snreg.nodes import read_nodes
from snreg.registration import CONFIDENT, METHODS, register
from snreg.registration.report import pair_rows
from snreg.session import read_intraop_nodes

__all__ = ["add_register_parser", "cmd_register"]


def add_register_parser(subparsers) -> None:
    p = subparsers.add_parser("register", help="register preop nodes to intraop nodes and pair them")
    p.add_argument("preop", help="preop node file (.csv or .mrk.json)")
    p.add_argument("intraop", help="intraop node file (.csv or .mrk.json) or session (.h5)")
    p.add_argument("--method", choices=METHODS, default="global")
    p.add_argument("--labels", action="store_true", help="use the anatomical labels (e.g. 'OBT R')")
    p.add_argument("--initial", help="rough intraop_from_preop: 4x4 text or JSON file")
    p.add_argument("--max-rotation", type=float, default=60.0, help="degrees (default 60)")
    p.add_argument("--max-translation", type=float, default=60.0, help="mm (default 60)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", help="write the result as JSON")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(func=cmd_register)


def cmd_register(args) -> int:
    try:
        preop = read_nodes(args.preop)
        is_session = Path(args.intraop).suffix.lower() in (".h5", ".hdf5")
        intraop = read_intraop_nodes(args.intraop) if is_session else read_nodes(args.intraop)
    except (NodeFileError, ValueError) as err:
        raise UserError(str(err)) from None
    try:
        result = register(preop.xyz, intraop.xyz, method=args.method,
                          preop_labels=preop.labels if args.labels else None,
                          intraop_labels=intraop.labels if args.labels else None,
                          initial=read_initial(args.initial), max_rotation_deg=args.max_rotation,
                          max_translation_mm=args.max_translation, seed=args.seed)
    except ValueError as err:
        raise UserError(str(err)) from None
    rows = pair_rows(preop, intraop, result)
    doc = {"method": result.method, "pairing_rule": result.pairing_rule, "rms_mm": result.rms_mm,
           "confident_threshold": CONFIDENT, "intraop_from_preop": result.transform.tolist(),
           "nodes": [row.as_json() for row in rows]}
    if args.output:
        Path(args.output).write_text(json.dumps(doc, indent=2), encoding="utf-8")
    if args.json:
        print(json.dumps(doc))
        return 0
    print(f"method {result.method}, RMS {result.rms_mm:.2f} mm, pairing rule {result.pairing_rule}")
    print(f"{'intraop':<10} {'label':<10} {'preop':<10} {'label':<10} {'dist mm':>8} {'conf':>6}")
    for row in rows:
        mark = "" if row.confident else "  (check)"
        print(f"{row.intraop_id:<10} {row.intraop_label:<10} {row.preop_id:<10} {row.preop_label:<10} "
              f"{row.distance_mm:>8.1f} {row.confidence:>6.2f}{mark}")
    return 0
