"""The text of the node files: CSV (docs/design.md, Contracts: Node files) and 3D Slicer markups (``.mrk.json``),
written from node sets and read into :class:`NodeRows`, from which :class:`snreg.nodes.NodeFile` makes its nodes and
landmarks (:mod:`snreg.nodes` says what each format holds). Apart from :mod:`snreg.nodes` because the two formats'
columns, cells and lists are one job and the node set they carry is another.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field

import numpy as np

from snreg.errors import NodeFileError
from snreg.landmarks import LANDMARK, NODE, in_vocabulary, kind_of, landmark_name

__all__ = ["NodeRows", "csv_text", "csv_rows", "slicer_document", "slicer_rows", "COV_COLUMNS", "LANDMARK_LIST",
           "SLICER_SCHEMA"]

COV_COLUMNS = ("cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz", "cov_zz")   # the upper triangle, row by row
_UPPER = np.triu_indices(3)

SLICER_SCHEMA = (
    "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/"
    "Resources/Schema/markups-schema-v1.0.3.json#"
)
LANDMARK_LIST = "landmarks"           # the name of the markups point list snreg writes its landmarks into


@dataclass
class NodeRows:
    """A node file's entries in file order, each with its ``kinds`` (node or landmark), before they are split into
    nodes and landmarks: ids, labels, ``xyz`` (N, 3) mm, ``counts`` (N,) or None, the file's ``frame`` and comments,
    ``cov`` (N, 3, 3) mm^2 or None."""

    kinds: list[str]
    ids: list[str]
    labels: list[str]
    xyz: np.ndarray
    counts: np.ndarray | None = None
    frame: str = ""
    comments: list[str] = field(default_factory=list)
    cov: np.ndarray | None = None


def csv_text(nodes, marks) -> str:
    """The CSV of the :class:`~snreg.nodes.NodeSet` ``nodes``, then the landmarks ``marks`` (``kind`` column only when
    there are landmarks); counts and covariance columns when either set has them (a set without: empty cells)."""
    with_counts = nodes.counts is not None or marks.counts is not None
    with_cov = nodes.cov is not None or marks.cov is not None
    out = io.StringIO()
    if nodes.frame:
        out.write(f"# frame: {nodes.frame}\n")
    for comment in nodes.comments:
        out.write(f"# {comment}\n")
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["id", "label", "x", "y", "z"] + (["counts"] if with_counts else [])
                    + (list(COV_COLUMNS) if with_cov else []) + (["kind"] if len(marks) else []))
    for kind, part in ((NODE, nodes), (LANDMARK, marks)):
        for k in range(len(part)):
            row = [part.ids[k], part.labels[k]] + [_fmt(v) for v in part.xyz[k]]
            if with_counts:
                row.append("" if part.counts is None else _fmt(part.counts[k]))
            if with_cov:
                row += [""] * 6 if part.cov is None else [_fmt(v) for v in part.cov[k][_UPPER]]
            writer.writerow(row + ([kind] if len(marks) else []))
    return out.getvalue()


def csv_rows(text: str, source: str = "node file", kind: str = NODE) -> NodeRows:
    """Parse a node CSV; ``kind``: what a row is whose ``kind`` cell is empty or absent. NodeFileError in one
    sentence naming the file and the row."""
    frame, comments, body, body_lines = "", [], [], []
    for line_no, line in enumerate(text.removeprefix("\ufeff").split("\n"), start=1):
        line = line.rstrip("\r")
        stripped = line.strip()
        if stripped.startswith("#"):
            comment = stripped.lstrip("#").strip()
            if comment.lower().startswith("frame:"):
                frame = comment.split(":", 1)[1].strip()
            elif comment:
                comments.append(comment)
        elif stripped:
            body.append(line)
            body_lines.append(line_no)
    if not body:
        raise NodeFileError(f"{source}: no header line; expected 'id,label,x,y,z'")
    try:
        rows = list(csv.reader(body))
    except csv.Error as err:
        raise NodeFileError(f"{source}: not a readable CSV ({err}); expected 'id,label,x,y,z' rows of a few "
                            "fields") from None
    header = [h.strip().lower() for h in rows[0]]
    missing = [c for c in ("id", "label", "x", "y", "z") if c not in header]
    if missing:
        raise NodeFileError(f"{source}: header lacks {', '.join(missing)}; expected 'id,label,x,y,z[,counts]"
                            "[,kind]'" + _separator_hint(body[0]))
    col = {}
    for index, name in enumerate(header):
        col.setdefault(name, index)
    ids, labels, xyz, counts, covs, kinds = [], [], [], [], [], []
    has_counts = "counts" in col
    has_cov = _cov_columns(col, source)
    for row_no, row in enumerate(rows[1:], start=1):
        where = f"data row {row_no} (line {body_lines[row_no]})"
        if len(row) < len(header):
            raise NodeFileError(f"{source}: {where} has {len(row)} fields, the header has {len(header)}")
        try:
            point = [float(row[col[a]]) for a in ("x", "y", "z")]
        except ValueError:
            raise NodeFileError(f"{source}: {where} has a coordinate (x, y, z) that is not a number") from None
        try:
            count = float(row[col["counts"]]) if has_counts and row[col["counts"]].strip() else math.nan
        except ValueError:
            raise NodeFileError(f"{source}: {where} has counts that are not a number "
                                f"({row[col['counts']].strip()!r}); leave the cell empty if unknown") from None
        if not row[col["id"]].strip():
            raise NodeFileError(f"{source}: {where} has an empty id; every node needs a unique id, e.g. SN1, "
                                "and every landmark its name")
        try:
            kinds.append(kind_of(row[col["kind"]] if "kind" in col else "", kind))
            ids.append(landmark_name(row[col["id"]]) if kinds[-1] == LANDMARK else row[col["id"]].strip())
        except ValueError as err:
            raise NodeFileError(f"{source}: {where}: {err}") from None
        labels.append(row[col["label"]].strip())
        xyz.append(point)
        counts.append(count)
        if has_cov:
            covs.append(_cov_cells([row[col[name]] for name in COV_COLUMNS], f"{source}: {where}"))
    return NodeRows(kinds, ids, labels, np.array(xyz).reshape(-1, 3), np.array(counts) if has_counts else None,
                    frame=frame, comments=comments, cov=np.array(covs).reshape(-1, 3, 3) if has_cov else None)


def slicer_document(nodes, landmarks) -> dict:
    """A Slicer markups document: the :class:`~snreg.nodes.NodeSet` ``nodes`` as a fiducial list (our id as point
    label, our anatomical label as description) and, when there are ``landmarks``, a second list named
    :data:`LANDMARK_LIST` (label = name).

    Positions are written as given with ``coordinateSystem`` LPS (DICOM patient space); counts have no place in
    the Slicer schema and are not written.
    """
    lists = [_slicer_list(nodes)] + ([_slicer_list(landmarks, LANDMARK_LIST)] if len(landmarks)
                                          else [])
    return {"@schema": SLICER_SCHEMA, "markups": lists}


def slicer_rows(doc: dict, source: str = "markups file", kind: str = NODE) -> NodeRows:
    """Nodes from the first fiducial list not named for landmarks, landmarks from the lists named for them and
    from vocabulary labels (:mod:`snreg.nodes`); each list's positions in LPS whichever system it says. ``kind``:
    what a control point of the nodes' list is when its label is not a vocabulary name."""
    ids, labels, xyz, kinds = [], [], [], []
    foreign = NodeFileError(f"{source}: not a 3D Slicer fiducial list (.mrk.json with markups/controlPoints)")
    try:
        fiducials = [m for m in doc["markups"] if m.get("type", "Fiducial") == "Fiducial"]
        named = [LANDMARK in str(m.get("name", "")).casefold() for m in fiducials]
        if not fiducials:
            raise foreign
        lists = [(m, False) for m, marks in zip(fiducials, named) if not marks][:1] + \
            [(m, True) for m, marks in zip(fiducials, named) if marks]
        for markup, marks in lists:
            system = str(markup.get("coordinateSystem", "LPS")).upper()
            for k, point in enumerate(markup.get("controlPoints", [])):
                label = point.get("label")
                kinds.append(LANDMARK if marks or in_vocabulary(label or "") else kind)
                if kinds[-1] == LANDMARK:
                    try:
                        ids.append(landmark_name("" if label is None else str(label)))
                    except ValueError as err:
                        raise NodeFileError(f"{source}: control point {k + 1} ({point.get('id', '?')}): "
                                            f"{err}") from None
                else:
                    ids.append(label or point.get("id") or f"F-{k + 1}")
                labels.append(point.get("description", ""))
                position = [float(v) for v in point["position"]]
                if len(position) != 3:
                    raise NodeFileError(f"{source}: control point {k + 1} has a position of {len(position)} "
                                        "numbers; every position needs x, y, z (mm)")
                xyz.append([-position[0], -position[1], position[2]] if system == "RAS" else position)
    except NodeFileError:
        raise
    except (KeyError, IndexError, TypeError, ValueError, AttributeError):
        raise foreign from None
    except OverflowError:
        raise NodeFileError(f"{source}: a control point position is a number too large for mm") from None
    return NodeRows(kinds, ids, labels, np.array(xyz, dtype=float).reshape(-1, 3), frame="LPS")


def _slicer_list(nodes: NodeSet, name: str = "") -> dict:
    """One fiducial list: our id as point label, our anatomical label as description; named when ``name``."""
    points = [
        {"id": str(k + 1), "label": nodes.ids[k], "description": nodes.labels[k], "associatedNodeID": "",
         "position": [float(v) for v in nodes.xyz[k]], "orientation": [-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0],
         "selected": True, "locked": False, "visibility": True, "positionStatus": "defined"}
        for k in range(len(nodes))
    ]
    return {"type": "Fiducial", **({"name": name} if name else {}), "coordinateSystem": "LPS", "coordinateUnits": "mm",
            "locked": False, "labelFormat": "%N-%d", "controlPoints": points, "measurements": []}


def _cov_columns(col: dict, source: str) -> bool:
    """Whether the header carries the covariance; NodeFileError when only some of its six columns are there."""
    present = [name for name in COV_COLUMNS if name in col]
    if present and len(present) < len(COV_COLUMNS):
        missing = [name for name in COV_COLUMNS if name not in col]
        raise NodeFileError(f"{source}: the covariance needs all six columns {','.join(COV_COLUMNS)} (mm^2); "
                            f"{', '.join(missing)} missing")
    return bool(present)


def _cov_cells(cells: list[str], where: str) -> np.ndarray:
    """(3, 3) mm^2 from a row's six covariance cells: NaN when all are empty (unknown); NodeFileError otherwise when
    one is empty or not a number."""
    cells = [cell.strip() for cell in cells]
    if not any(cells):
        return np.full((3, 3), np.nan)
    try:
        upper = [float(cell) for cell in cells]
    except ValueError:
        raise NodeFileError(f"{where} has a covariance cell that is not a number (mm^2); leave all six empty if "
                            "unknown") from None
    matrix = np.zeros((3, 3))
    matrix[_UPPER] = upper
    return matrix + np.triu(matrix, 1).T


def _separator_hint(header: str) -> str:
    """A note naming the separator when the header line was written with one other than a comma."""
    for separator, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "bars")):
        if separator in header and "," not in header:
            return (f"; the header is separated by {name}: node files are comma-separated (save as 'CSV UTF-8 (comma "
                    "delimited)', with a point as the decimal mark)")
    if "," not in header and len(header.split()) >= 5:
        return "; the header is separated by spaces: node files are comma-separated"
    return ""


def _fmt(value: float) -> str:
    if math.isnan(value):
        return ""
    text = f"{value:.6f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text
