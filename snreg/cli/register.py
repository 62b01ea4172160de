"""``snreg register PREOP.csv INTRAOP.(csv|h5)`` or ``snreg register SESSION.h5``: register the preop nodes to the
intraop nodes and pair them; with a session alone, both node sets and the initial alignment come from it.

Each side's covariances (a stored node's own error, a hot spot's from the segmentation; a session's nodes or a CSV's
``cov_*`` columns) are given to ``register`` when every node of that side has one; ``--no-covariances`` registers
without them, for comparison. The output says what was used and what not, and why (labels, landmarks, covariances:
:mod:`snreg.registration.wording`, the words and digits every screen shares). What a registration is given is decided
in one place, :func:`snreg.workflow.node_registration.register_nodes`, which the headless demo calls too (with the
labels typed on the phantom), so ``snreg register SESSION.h5 --labels`` repeats the demo's confidences.

Anatomical landmarks come with the nodes: a CSV's rows of ``kind`` landmark, a markups file's landmark points
(:mod:`snreg.nodes`), a session's stored and preop landmarks; ``--preop-landmarks``/``--intraop-landmarks`` add a file
of landmarks alone (a Slicer point list saved on its own). They are paired by name and given to ``register``, so one
or two nodes register when landmarks make three points; each pair's residual and leave-one-out residual are printed,
and the pairs the registration left out as contradicting the rest are named as suspect.

The start (:mod:`snreg.workflow.registration_start`): ``--initial`` when given; else gravity when both downs are known
(the preop one from the SPECT's patient position and the table's tilt, as ``snreg preop`` records them in the node
file's comments or the session keeps them with its preop nodes; the intraop one from the session's chain), which
``--down-preop``, ``--down-intraop`` and ``--tilt`` override; else the session's stored initial alignment; else the
identity, as before gravity. A SPECT whose patient position gives no down is refused then, saying what to do. The
output says which start it used and why."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from snreg.cli.common import check_output_file, down_vector, finite_float, float_range, read_initial, seed, write_text
from snreg.errors import UserError

if TYPE_CHECKING:                       # numpy and the node files are imported when a command runs, not for --help
    import numpy as np

    from snreg.nodes import NodeFile
    from snreg.preop.gravity import PreopDown
    from snreg.workflow.registration_start import GravityStart

__all__ = ["add_register_parser", "cmd_register", "METHOD_CHOICES"]

METHOD_CHOICES = ("icp", "cpd", "chamfer", "global")      # snreg.registration.METHODS (a test keeps them equal)
MAX_TILT_DEG = 60.0           # snreg.preop.gravity.MAX_TILT_DEG, stated here: building the parser imports no numpy
TO_GIVE_PREOP = ("give the down in the SPECT's frame with --down-preop X,Y,Z (LPS: 0,1,0 for a supine patient on a "
                 "level table, 0,0.87,0.5 tilted 30 degrees head down) or a rough alignment with --initial")


def add_register_parser(subparsers) -> None:
    p = subparsers.add_parser("register", help="register preop nodes to intraop nodes and pair them")
    p.add_argument("preop", help="preop node file (.csv or .mrk.json), or a session (.h5) holding both node sets")
    p.add_argument("intraop", nargs="?", help="intraop node file (.csv or .mrk.json) or session (.h5)")
    p.add_argument("--method", choices=METHOD_CHOICES, default="global", help="registration method")
    p.add_argument("--labels", action="store_true", help="use the anatomical labels (e.g. 'OBT R')")
    p.add_argument("--initial", help="rough intraop_from_preop: 4x4 text or JSON file, or a session (.h5) whose last "
                                     "registration's initial alignment is used (default: gravity when both downs are "
                                     "known, else the session's, when the preop nodes come from it)")
    p.add_argument("--down-preop", type=down_vector, metavar="X,Y,Z",
                   help="gravity's direction in the preop frame (LPS), the table's tilt included (default: from the "
                        "SPECT's patient position and --tilt, as snreg preop records them)")
    p.add_argument("--down-intraop", type=down_vector, metavar="X,Y,Z",
                   help="gravity's direction in the intraop (trocar) frame (default: the session's, as the IMU on "
                        "the endoscope measures it, through the trocar calibration)")
    p.add_argument("--tilt", type=float_range(0.0, MAX_TILT_DEG, "degrees", low_open=False), metavar="DEG",
                   help="the table's head-down tilt (Trendelenburg) that turns the SPECT's down (default: the one "
                        "recorded with the preop nodes: snreg preop's --tilt, else 30)")
    p.add_argument("--max-rotation", type=finite_float, default=60.0, help="degrees from the initial alignment")
    p.add_argument("--max-translation", type=finite_float, default=60.0, help="mm from the initial alignment")
    p.add_argument("--seed", type=seed, default=0, help="random seed of the search")
    p.add_argument("--no-covariances", action="store_true",
                   help="ignore the nodes' own covariances (used by default when every node of a side has one)")
    p.add_argument("--preop-landmarks", metavar="FILE",
                   help="anatomical landmarks on the CT (patient LPS, mm): a .mrk.json point list or CSV of landmarks "
                        "alone, labels = names; added to those the preop file holds (kind landmark)")
    p.add_argument("--intraop-landmarks", metavar="FILE",
                   help="landmarks touched in surgery (the intraop frame, mm), a file of landmarks alone; added to "
                        "those the intraop file or session holds")
    p.add_argument("--landmark-sd", type=finite_float, default=2.0, metavar="MM",
                   help="a landmark pair's own error, sd per axis in mm (default 2)")
    p.add_argument("-o", "--output", help="write the result as JSON")
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")
    p.set_defaults(func=cmd_register)


def _is_session(path: str) -> bool:
    return Path(path).suffix.lower() in (".h5", ".hdf5")


@dataclass(frozen=True, eq=False)
class Inputs:
    """What ``snreg register`` registers: each side's nodes and landmarks, a session's initial alignment, the patient
    position and tilt recorded with the preop nodes (None: none recorded), the intraop down (None, with why, when
    unknown)."""

    preop: NodeFile
    intraop: NodeFile
    initial: np.ndarray | None = None
    preop_down: PreopDown | None = None
    intraop_down: np.ndarray | None = None
    intraop_unknown: str = ""


def _inputs(args) -> Inputs:
    """Both sides from two files (a session as the intraop one; a node file's comments record the SPECT's patient
    position), or both node sets, their landmarks, the preop down and the initial alignment kept with the last
    registration from one session; the landmark files of the options added; the intraop down from a session's chain."""
    from snreg.nodes import NodeFile, read_node_file
    from snreg.preop.gravity import PreopDown
    from snreg.session import Session

    if args.intraop is None:
        if not _is_session(args.preop):
            raise UserError(f"{args.preop}: give the preop and the intraop node files, or one session (.h5)")
        with Session.open(args.preop) as session:
            preop, initial, preop_down = session.preop_nodes(), session.last_initial(), session.preop_down()
            intraop = NodeFile(session.intraop_nodes(), session.intraop_landmarks())
            preop = None if preop is None else NodeFile(preop, session.preop_landmarks())
            down, unknown = _intraop_down(session)
        if preop is None:
            raise UserError(f"{args.preop}: the session holds no preop nodes; give PREOP.csv {args.preop}")
    else:
        preop, initial = read_node_file(args.preop), None
        preop_down = PreopDown.from_comments(preop.nodes.comments, args.preop)
        if _is_session(args.intraop):
            with Session.open(args.intraop) as session:
                intraop = NodeFile(session.intraop_nodes(), session.intraop_landmarks())
                down, unknown = _intraop_down(session)
        else:
            intraop = read_node_file(args.intraop)
            down, unknown = None, f"{args.intraop} is a node file, which carries no down"
    return Inputs(_with_landmarks(preop, args.preop_landmarks, preop=True),
                  _with_landmarks(intraop, args.intraop_landmarks),
                  initial, preop_down, down, unknown)


def _intraop_down(session):
    """(the down in the session's trocar frame, "") or (None, why it is unknown)."""
    from snreg.errors import SessionError

    try:
        return session.intraop_down(), ""
    except SessionError as err:
        return None, str(err)


@dataclass(frozen=True, eq=False)
class _Start:
    """Where the registration starts: ``kind`` "gravity" (``gravity``), "initial" (``initial``) or "identity", and
    ``words`` that say so."""

    kind: str
    words: str
    initial: np.ndarray | None = None
    gravity: GravityStart | None = None

    def as_json(self) -> dict:
        out = {"kind": self.kind, "words": self.words}
        if self.gravity is not None:
            out.update(down_preop=self.gravity.preop.tolist(), down_intraop=self.gravity.intraop.tolist(),
                       preop_source=self.gravity.preop_source, intraop_source=self.gravity.intraop_source)
        return out


def _start(args, inputs: Inputs) -> _Start:
    """``--initial``; else gravity when both downs are known (the options override what the files say); else the
    session's stored initial alignment; else the identity. UserError in one sentence for options that contradict each
    other, a down asked for but unknown, or a SPECT whose patient position gives none."""
    from snreg.errors import PreopError
    from snreg.workflow.registration_start import INTRAOP_SOURCE, GravityStart

    asked = [flag for flag, value in (("--down-preop", args.down_preop), ("--down-intraop", args.down_intraop),
                                      ("--tilt", args.tilt)) if value is not None]
    if args.initial:
        if asked:
            raise UserError(f"--initial gives the start, {' and '.join(asked)} gravity's; give one or the other")
        return _Start("initial", f"start: the initial alignment of {args.initial}", initial=read_initial(args.initial))
    if args.down_preop is not None and args.tilt is not None:
        raise UserError("--down-preop gives the preop down with the table's tilt included; drop --tilt")
    preop_down, preop_problem = inputs.preop_down, ""
    if args.down_preop is not None:
        preop, preop_source, preop_down = _unit(args.down_preop), "given with --down-preop", None
    elif preop_down is None:
        preop, preop_problem = None, f"{args.preop} records no patient position for its preop nodes"
    else:
        try:
            preop_down = preop_down if args.tilt is None else preop_down.with_tilt(args.tilt)
            preop, preop_source = preop_down.vector, preop_down.source
        except PreopError as err:
            preop, preop_problem = None, f"{args.preop}: {err}"
    intraop = _unit(args.down_intraop) if args.down_intraop is not None else inputs.intraop_down
    if preop is not None and intraop is not None:
        intraop_source = INTRAOP_SOURCE if args.down_intraop is None else "given with --down-intraop"
        gravity = GravityStart(preop, intraop, preop_source, intraop_source, preop_down)
        return _Start("gravity", gravity.words, gravity=gravity)
    if preop is None and (asked or inputs.preop_down is not None):
        raise UserError(f"{preop_problem}; {TO_GIVE_PREOP}")
    if asked:
        raise UserError(f"{inputs.intraop_unknown}; give the down in the intraop (trocar) frame with --down-intraop "
                        "X,Y,Z, or a rough alignment with --initial")
    unknown = preop_problem or inputs.intraop_unknown
    if inputs.initial is not None:
        return _Start("initial", f"start: the session's stored initial alignment (not gravity: {unknown})",
                      initial=inputs.initial)
    return _Start("identity", f"start: the identity (not gravity: {unknown})")


def _unit(vector):
    """A down given on the command line (three numbers, not all zero) as a unit vector."""
    import numpy as np

    vector = np.asarray(vector, dtype=float)
    return vector / np.linalg.norm(vector)


def _with_landmarks(read, path: str | None, preop: bool = False):
    """``read`` (a NodeFile) with the landmarks of the file at ``path`` added; ValueError for a name given twice. A
    ``preop`` file is read as the app's "Landmarks..." reads it (:func:`~snreg.workflow.preop_landmarks.
    read_preop_landmarks`: in patient LPS, a RAS CSV turned, another frame refused)."""
    from snreg.nodes import NodeFile, NodeSet, read_landmarks
    from snreg.workflow.preop_landmarks import read_preop_landmarks

    if path is None:
        return read
    more = read_preop_landmarks(path) if preop else read_landmarks(path)
    twice = sorted(set(more.ids) & set(read.landmarks.ids))
    if twice:
        raise ValueError(f"{path}: landmark {twice[0]!r} is in the node file too; give each landmark once")
    both = NodeSet(read.landmarks.ids + more.ids, read.landmarks.labels + more.labels,
                   [*read.landmarks.xyz, *more.xyz], frame=read.landmarks.frame or more.frame)
    return NodeFile(read.nodes, both)


def cmd_register(args) -> int:
    from snreg.errors import NodeFileError, NoFitError, SessionError
    from snreg.registration import CONFIDENT
    from snreg.registration.naming import PREOP_MARK, ids_collide, marked_missing, marked_rows, pair_text
    from snreg.registration.landmark_report import landmark_notes, landmark_rows, unpaired_landmarks
    from snreg.registration.report import missing_nodes, node_warnings, pair_expected_mm, pair_rows
    from snreg.registration.wording import (HOT_SPOT_LEGEND, LOO_LEGEND, check_words, confidence_text, down_words,
                                            loo_text, rule_words)
    from snreg.workflow.node_registration import node_covariances, register_nodes

    if args.output:
        check_output_file(args.output, "result")
    try:
        inputs = _inputs(args)
    except (NodeFileError, SessionError, ValueError, OSError) as err:
        raise UserError(str(err)) from None
    preop, intraop, start = inputs.preop.nodes, inputs.intraop.nodes, _start(args, inputs)
    marks = (inputs.preop.landmarks, inputs.intraop.landmarks)
    covariances = node_covariances(preop, intraop, not args.no_covariances)
    try:
        result = register_nodes(inputs.preop, inputs.intraop, method=args.method, labels=args.labels,
                                covariances=not args.no_covariances, initial=start.initial,
                                max_rotation_deg=args.max_rotation, max_translation_mm=args.max_translation,
                                seed=args.seed, landmark_sd_mm=args.landmark_sd,
                                down=None if start.gravity is None else start.gravity.down)
    except NoFitError:
        raise UserError(_no_fit_text(args, start)) from None
    except ValueError as err:
        raise UserError(str(err)) from None
    rows = pair_rows(preop, intraop, result)
    missing = missing_nodes(preop, result)
    used = _used(args, result, preop, intraop, covariances)
    weighed = intraop if covariances["intraop"] is not None else replace(intraop, cov=None)
    typical, bound = (pair_expected_mm(weighed, result, level) for level in (0.5, 0.9))
    doc = {"method": result.method, "pairing_rule": result.pairing_rule, "rms_mm": result.rms_mm,
           "confident_threshold": CONFIDENT, "intraop_from_preop": result.transform.tolist(),
           "initial": result.initial.tolist(), "start": start.as_json(), "used": used.as_json(),
           "covariances": {side: covariances[side] is not None for side in ("intraop", "preop")},
           "nodes": [{**row.as_json(), "leave_one_out_typical_mm": _mm(typical[k]), "leave_one_out_bound_mm":
                      _mm(bound[k])} for k, row in enumerate(rows)],
           "missing": [node.as_json() for node in missing],
           "warnings": node_warnings(rows) + landmark_notes(result, marks[0].ids, marks[1].ids),
           "landmark_sd_mm": args.landmark_sd, "landmarks": [row.as_json() for row in landmark_rows(result)],
           "landmarks_suspect": list(result.landmarks_suspect), "landmarks_checkable": result.landmarks_checkable,
           "landmarks_unpaired": unpaired_landmarks(marks[0].ids, marks[1].ids)}
    if args.output:
        write_text(args.output, json.dumps(doc, indent=2), "result")
    if args.json:
        print(json.dumps(doc))
        return 0
    print(f"method {result.method}, RMS {result.rms_mm:.2f} mm; pairing: {rule_words(result.pairing_rule)}")
    print(start.words)
    if start.gravity is not None:
        for side, frame, down, source in (("preop", "LPS", start.gravity.preop, start.gravity.preop_source),
                                          ("intraop", "trocar", start.gravity.intraop, start.gravity.intraop_source)):
            print(f"  {down_words(side)}: {', '.join(f'{v:.3f}' for v in down)}, {source}")
    print(used.text())
    if ids_collide(preop.ids, intraop.ids):
        print(f"the preop ids repeat intraop ids: preop nodes are shown as {PREOP_MARK}<id>")
    shown = marked_rows(rows, preop.ids)
    width = max([len("intraop -> hot spot")] + [len(pair_text(row)) for row in shown])
    loo = [loo_text(row.leave_one_out_mm, typical[k], bound[k]) for k, row in enumerate(shown)]
    loo_width = max([len("loo mm")] + [len(text) for text in loo])
    print(f"{'intraop -> hot spot':<{width}} {'labels':<21} {'dist mm':>8} {'loo mm':<{loo_width}} {'conf':>5}")
    for row, loo_shown in zip(shown, loo):
        labels = f"{row.intraop_label or '-'} -> {row.preop_label or '-'}" if row.paired else row.intraop_label
        mark = check_words(row.confidence)
        print(f"{pair_text(row):<{width}} {labels:<21} {row.distance_mm:>8.1f} {loo_shown:<{loo_width}} "
              f"{confidence_text(row.confidence):>5}" + (f"  {mark}" if mark else ""))
    for node in marked_missing(missing, intraop.ids, preop.ids):
        x, y, z = node.mapped_xyz
        print(f"missing {node.preop_id} ({node.preop_label or 'no label'}): expected at ({x:.1f}, {y:.1f}, {z:.1f}) mm, "
              f"within {node.bound_mm:.1f} mm (90%)")
    _print_landmarks(landmark_rows(result), args.landmark_sd)
    for text in node_warnings(shown) + landmark_notes(result, marks[0].ids, marks[1].ids):
        print(f"warning: {text}")
    print(f"{HOT_SPOT_LEGEND};\n{LOO_LEGEND}")
    return 0


def _mm(value: float):
    """mm for JSON: 3 decimals, NaN as null."""
    return None if value != value else round(float(value), 3)


def _used(args, result, preop, intraop, covariances: dict):
    """What this registration used (:class:`~snreg.registration.wording.UsedInputs`), each absent input with why and
    the option that would add it."""
    from snreg.registration.wording import labels_given, used_inputs

    lacking = [f"the {side} nodes carry none" for side, nodes in (("preop", preop), ("intraop", intraop))
               if not labels_given(nodes.labels)]
    labels_why = "; ".join(lacking) if lacking else "not asked for: add --labels to forbid left/right crossings"
    if args.no_covariances:
        cov_why = "--no-covariances"
    else:
        cov_why = "; ".join(f"the {side} nodes {'have none' if nodes.cov is None else 'lack some'}"
                            for side, nodes in (("intraop", intraop), ("preop", preop)) if covariances[side] is None)
    return used_inputs(result, labels=args.labels and not lacking, intraop_cov=covariances["intraop"] is not None,
                       preop_cov=covariances["preop"] is not None, labels_why=labels_why, cov_why=cov_why,
                       landmarks_why="none named on both sides; --preop-landmarks and --intraop-landmarks add them")


def _no_fit_text(args, start: _Start) -> str:
    """One sentence: no pairing fits from this start, and what to change (the options that would)."""
    if start.gravity is not None:
        return (f"no pairing fits from gravity's start (every heading, the tilt near the two downs, the centroids "
                f"within {args.max_translation:g} mm): check the table tilt (--tilt) and the patient position, give a "
                "rough alignment with --initial, add --labels, or widen --max-translation")
    return (f"no pairing fits within {args.max_rotation:g} degrees and {args.max_translation:g} mm of the "
            f"{'given' if start.initial is not None else 'identity'} initial alignment: give a rough alignment "
            "with --initial (a 4x4 file or the session) or the downs (--down-preop, --down-intraop), add --labels, "
            "or widen --max-rotation and --max-translation")


def _print_landmarks(rows, sd_mm: float) -> None:
    """The landmark pairs' table: residual, leave-one-out residual, and SUSPECT where one was left out."""
    if not rows:
        return
    width = max(len("landmark"), *(len(row.name) for row in rows))
    pairs = f"{len(rows)} pair{'s' if len(rows) > 1 else ''}"
    print(f"landmarks: {pairs}, each with {sd_mm:g} mm of its own error per axis")
    print(f"{'landmark':<{width}} {'dist mm':>8} {'loo mm':>7}")
    for row in rows:
        print(f"{row.name:<{width}} {row.residual_mm:>8.1f} {row.leave_one_out_mm:>7.1f}"
              + ("  SUSPECT: left out of the fit" if row.suspect else ""))

