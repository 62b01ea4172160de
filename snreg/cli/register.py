"""``snreg register PREOP.csv INTRAOP.(csv|h5)`` or ``snreg register SESSION.h5``: register the preop nodes to the
intraop nodes and pair them; with a session alone, both node sets and the initial alignment come from it.

Each side's covariances (a stored node's own error, a hot spot's from the segmentation; a session's nodes or a CSV's
``cov_*`` columns) are given to ``register`` when every node of that side has one; ``--no-covariances`` registers
without them, for comparison. The output says which were used."""

from __future__ import annotations

import json
from pathlib import Path

from snreg.cli.common import check_output_file, finite_float, read_initial, seed, write_text
from snreg.errors import UserError

__all__ = ["add_register_parser", "cmd_register", "METHOD_CHOICES"]

METHOD_CHOICES = ("icp", "cpd", "chamfer", "global")      # snreg.registration.METHODS (a test keeps them equal)


def add_register_parser(subparsers) -> None:
    p = subparsers.add_parser("register", help="register preop nodes to intraop nodes and pair them")
    p.add_argument("preop", help="preop node file (.csv or .mrk.json), or a session (.h5) holding both node sets")
    p.add_argument("intraop", nargs="?", help="intraop node file (.csv or .mrk.json) or session (.h5)")
    p.add_argument("--method", choices=METHOD_CHOICES, default="global", help="registration method")
    p.add_argument("--labels", action="store_true", help="use the anatomical labels (e.g. 'OBT R')")
    p.add_argument("--initial", help="rough intraop_from_preop: 4x4 text or JSON file, or a session (.h5) whose last "
                                     "registration's initial alignment is used (default: the session's, when the "
                                     "preop nodes come from it)")
    p.add_argument("--max-rotation", type=finite_float, default=60.0, help="degrees from the initial alignment")
    p.add_argument("--max-translation", type=finite_float, default=60.0, help="mm from the initial alignment")
    p.add_argument("--seed", type=seed, default=0, help="random seed of the search")
    p.add_argument("--no-covariances", action="store_true",
                   help="ignore the nodes' own covariances (used by default when every node of a side has one)")
    p.add_argument("-o", "--output", help="write the result as JSON")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(func=cmd_register)


def _is_session(path: str) -> bool:
    return Path(path).suffix.lower() in (".h5", ".hdf5")


def _inputs(args):
    """(preop, intraop, the session's initial alignment or None): from two files, or both node sets and the initial
    alignment kept with its last registration from one session."""
    from snreg.nodes import read_nodes
    from snreg.session import Session, read_intraop_nodes

    if args.intraop is None:
        if not _is_session(args.preop):
            raise UserError(f"{args.preop}: give the preop and the intraop node files, or one session (.h5)")
        with Session.open(args.preop) as session:
            preop, intraop, initial = session.preop_nodes(), session.intraop_nodes(), session.last_initial()
        if preop is None:
            raise UserError(f"{args.preop}: the session holds no preop nodes; give PREOP.csv {args.preop}")
        return preop, intraop, initial
    preop = read_nodes(args.preop)
    intraop = read_intraop_nodes(args.intraop) if _is_session(args.intraop) else read_nodes(args.intraop)
    return preop, intraop, None


def cmd_register(args) -> int:
    from snreg.errors import NodeFileError, NoFitError, SessionError
    from snreg.registration import CONFIDENT, register
    from snreg.registration.naming import PREOP_MARK, ids_collide, marked_missing, marked_rows, pair_text
    from snreg.registration.report import missing_nodes, node_warnings, pair_rows

    if args.output:
        check_output_file(args.output, "result")
    try:
        preop, intraop, session_initial = _inputs(args)
    except (NodeFileError, SessionError, ValueError, OSError) as err:
        raise UserError(str(err)) from None
    initial = read_initial(args.initial) if args.initial else session_initial
    covariances = _covariances(preop, intraop, args.no_covariances)
    try:
        result = register(preop.xyz, intraop.xyz, method=args.method,
                          preop_labels=preop.labels if args.labels else None,
                          intraop_labels=intraop.labels if args.labels else None,
                          initial=initial, max_rotation_deg=args.max_rotation,
                          max_translation_mm=args.max_translation, seed=args.seed,
                          intraop_cov=covariances["intraop"], preop_cov=covariances["preop"])
    except NoFitError:
        raise UserError(f"no pairing fits within {args.max_rotation:g} degrees and {args.max_translation:g} mm of the "
                        f"{'given' if initial is not None else 'identity'} initial alignment: give a rough alignment "
                        "with --initial (a 4x4 file or the session), add --labels, or widen --max-rotation and "
                        "--max-translation") from None
    except ValueError as err:
        raise UserError(str(err)) from None
    rows = pair_rows(preop, intraop, result)
    missing = missing_nodes(preop, result)
    doc = {"method": result.method, "pairing_rule": result.pairing_rule, "rms_mm": result.rms_mm,
           "confident_threshold": CONFIDENT, "intraop_from_preop": result.transform.tolist(),
           "initial": result.initial.tolist(),
           "covariances": {side: covariances[side] is not None for side in ("intraop", "preop")},
           "nodes": [row.as_json() for row in rows],
           "missing": [node.as_json() for node in missing], "warnings": node_warnings(rows)}
    if args.output:
        write_text(args.output, json.dumps(doc, indent=2), "result")
    if args.json:
        print(json.dumps(doc))
        return 0
    print(f"method {result.method}, RMS {result.rms_mm:.2f} mm, pairing rule {result.pairing_rule}")
    print(_covariance_text(covariances, preop, intraop, args.no_covariances))
    if ids_collide(preop.ids, intraop.ids):
        print(f"the preop ids repeat intraop ids: preop nodes are shown as {PREOP_MARK}<id>")
    shown = marked_rows(rows, preop.ids)
    width = max([len("intraop -> hot spot")] + [len(pair_text(row)) for row in shown])
    print(f"{'intraop -> hot spot':<{width}} {'labels':<21} {'dist mm':>8} {'loo mm':>7} {'conf':>6}")
    for row in shown:
        mark = "" if row.confident else "  (check)"
        labels = f"{row.intraop_label or '-'} -> {row.preop_label or '-'}" if row.paired else row.intraop_label
        print(f"{pair_text(row):<{width}} {labels:<21} "
              f"{row.distance_mm:>8.1f} {row.leave_one_out_mm:>7.1f} {row.confidence:>6.2f}{mark}")
    for node in marked_missing(missing, intraop.ids, preop.ids):
        x, y, z = node.mapped_xyz
        print(f"missing {node.preop_id} ({node.preop_label or 'no label'}): expected at ({x:.1f}, {y:.1f}, {z:.1f}) mm, "
              f"within {node.bound_mm:.1f} mm (90%)")
    for text in node_warnings(shown):
        print(f"warning: {text}")
    print("hot spot: the SPECT node a removed node came from (several may share one: 'with'; none: from no imaged "
          "hot spot);\nloo: the node's distance when the other pairs alone register (a large value flags a suspect "
          "node)")
    return 0


def _covariances(preop, intraop, ignore: bool) -> dict:
    """``{"intraop", "preop"}``: each side's covariances (N, 3, 3) mm^2 when every node of it has one, else None (and
    both None when ``ignore``)."""
    if ignore:
        return {"intraop": None, "preop": None}
    return {"intraop": intraop.known_cov, "preop": preop.known_cov}


def _covariance_text(covariances: dict, preop, intraop, ignore: bool) -> str:
    """One line: which sides' own covariances weighed the nodes, and why a side's did not."""
    if ignore:
        return "covariances: not used (--no-covariances); every node weighed alike"
    used = [side for side in ("intraop", "preop") if covariances[side] is not None]
    missing = [f"{side} nodes {'have none' if nodes.cov is None else 'lack some'}"
               for side, nodes in (("intraop", intraop), ("preop", preop)) if covariances[side] is None]
    text = f"covariances: each {' and '.join(used)} node weighed by its own" if used else \
        "covariances: none used; every node weighed alike"
    return f"{text} ({'; '.join(missing)})" if missing else text
