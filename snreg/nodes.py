"""Node sets and their files: CSV (docs/design.md, Contracts) and 3D Slicer markups (``.mrk.json``).

A :class:`NodeSet` is the one currency between preop, session and registration:
ids, anatomical labels (``"OBT R"``), positions in mm, optional gamma counts and optional covariances (each node's
own error, mm^2, in the set's frame: a SPECT hot spot's from the segmentation, a stored node's from the tracker and
chain). A CSV carries the covariance in six columns ``cov_xx,cov_xy,cov_xz,cov_yy,cov_yz,cov_zz`` (mm^2; a node's
cells all empty when its covariance is unknown).

A file may also hold anatomical landmarks (issue 29), which :class:`NodeFile` keeps apart from its nodes: a landmark is
never counted, paired or registered as a node (:func:`read_nodes` gives the nodes alone). A CSV row is a landmark when
its ``kind`` column says ``landmark`` (empty or no column: a node), its ``id`` the name. In 3D Slicer markups (no kind)
a control point is a landmark in a point list named with "landmark" (snreg writes its landmarks so) or when its label
is a vocabulary name (:data:`snreg.landmarks.LANDMARKS`, any case); its label is its name. A file read as landmarks
(:func:`read_landmarks`, e.g. a Slicer point list saved on its own) has landmarks only, whatever their names. Names
pass :func:`snreg.landmarks.landmark_name`.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from snreg.errors import NodeFileError
from snreg.files import atomic_write, read_text_file
from snreg.landmarks import LANDMARK, NODE, in_vocabulary, kind_of, landmark_name

__all__ = ["NodeSet", "NodeFile", "NodeFileError", "read_nodes", "read_node_file", "read_landmarks", "write_nodes",
           "no_nodes", "PREOP_PREFIX", "INTRAOP_PREFIX", "LANDMARK_LIST"]

# The ids snreg itself gives: preop nodes from a SPECT are P1, P2, ... (hottest first), intraop nodes stored in
# surgery SN1, SN2, ..., so "SN1 -> P3" cannot be misread. Ids read from a user's file may be anything.
PREOP_PREFIX = "P"
INTRAOP_PREFIX = "SN"

MAX_NODE_FILE_BYTES = 16 << 20        # a node file holds tens of nodes; 16 MB holds hundreds of thousands
COV_COLUMNS = ("cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz", "cov_zz")   # the upper triangle, row by row
_UPPER = np.triu_indices(3)

SLICER_SCHEMA = (
    "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/"
    "Resources/Schema/markups-schema-v1.0.3.json#"
)
LANDMARK_LIST = "landmarks"           # the name of the markups point list snreg writes its landmarks into


@dataclass
class NodeSet:
    """Nodes with ids (unique str), labels (str, may be empty), xyz (N, 3) mm, counts (N,) or None, and ``cov``
    (N, 3, 3) mm^2 or None: each node's own error covariance in the set's frame (a node's NaN when unknown).

    ``frame`` names the coordinate frame (``"trocar"``, ``"LPS"``...) when known.
    """

    ids: list[str]
    labels: list[str]
    xyz: np.ndarray
    counts: np.ndarray | None = None
    frame: str = ""
    comments: list[str] = field(default_factory=list)
    cov: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.ids = [str(i) for i in self.ids]
        self.labels = [str(label) for label in self.labels]
        self.xyz = np.asarray(self.xyz, dtype=float).reshape(-1, 3)
        n = len(self.xyz)
        if len(self.ids) != n or len(self.labels) != n:
            raise ValueError(f"a node set needs one id and one label per node: {n} positions, "
                             f"{len(self.ids)} ids, {len(self.labels)} labels")
        if any(not i.strip() for i in self.ids):
            raise ValueError(f"node {[i.strip() for i in self.ids].index('') + 1} has an empty id; every node needs one, e.g. SN1")
        if len(set(self.ids)) != n:
            dup = sorted({i for i in self.ids if self.ids.count(i) > 1})
            raise ValueError(f"node ids must be unique; repeated: {', '.join(dup)}")
        if not np.all(np.isfinite(self.xyz)):
            raise ValueError("node positions must be finite numbers (found NaN or infinity)")
        if self.counts is not None:
            self.counts = np.asarray(self.counts, dtype=float).reshape(-1)
            if len(self.counts) != n:
                raise ValueError(f"counts has {len(self.counts)} values for {n} nodes")
        if self.cov is not None:
            self.cov = np.asarray(self.cov, dtype=float)
            if self.cov.shape != (n, 3, 3):
                raise ValueError(f"cov must hold one 3x3 covariance (mm^2) per node: ({n}, 3, 3), got {self.cov.shape}")

    @property
    def known_cov(self) -> np.ndarray | None:
        """(N, 3, 3) mm^2 when every node's covariance is known (finite), else None."""
        return self.cov if self.cov is not None and np.all(np.isfinite(self.cov)) else None

    def __len__(self) -> int:
        return len(self.xyz)

    def moved(self, transform, frame: str = "", comments: list[str] | None = None) -> "NodeSet":
        """These nodes under a rigid ``transform`` (4, 4) into ``frame``: positions mapped, covariances turned with
        them; ids, labels and counts kept."""
        matrix = np.asarray(transform, dtype=float)
        rotation = matrix[:3, :3]
        return NodeSet(list(self.ids), list(self.labels), self.xyz @ rotation.T + matrix[:3, 3],
                       None if self.counts is None else self.counts.copy(), frame=frame,
                       comments=list(comments or []), cov=None if self.cov is None else rotation @ self.cov @ rotation.T)

    @classmethod
    def from_xyz(cls, xyz, labels=None, prefix: str = INTRAOP_PREFIX, **kwargs) -> "NodeSet":
        """Nodes named ``<prefix>1..<prefix>n`` (default ``SN1..SNn``) from bare positions."""
        xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
        labels = list(labels) if labels is not None else [""] * len(xyz)
        return cls([f"{prefix}{k + 1}" for k in range(len(xyz))], labels, xyz, **kwargs)

    def to_csv(self) -> str:
        """The node CSV of these nodes (:meth:`NodeFile.to_csv`)."""
        return NodeFile(self).to_csv()

    @classmethod
    def from_csv(cls, text: str, source: str = "node file") -> "NodeSet":
        """The nodes of a node CSV; its landmarks are left out (:meth:`NodeFile.from_csv` keeps them)."""
        return NodeFile.from_csv(text, source).nodes

    def subset(self, keep) -> "NodeSet":
        """The nodes at ``keep`` (indices or a boolean mask), with their counts and covariances; frame kept."""
        keep = np.asarray(keep)
        keep = np.flatnonzero(keep) if keep.dtype == bool else keep.astype(int).reshape(-1)
        return NodeSet([self.ids[k] for k in keep], [self.labels[k] for k in keep], self.xyz[keep],
                       None if self.counts is None else self.counts[keep], frame=self.frame,
                       cov=None if self.cov is None else self.cov[keep])


def no_nodes(frame: str = "") -> NodeSet:
    """An empty node set (no landmarks, say)."""
    return NodeSet([], [], np.zeros((0, 3)), frame=frame)


@dataclass
class NodeFile:
    """What a node file holds: its ``nodes`` and, apart, its anatomical ``landmarks`` (a :class:`NodeSet` whose ids are
    the landmark names, empty when there are none). Registration counts and pairs the nodes alone and takes the
    landmarks by name (``register(..., preop_landmarks=file.landmarks)``)."""

    nodes: NodeSet
    landmarks: NodeSet = field(default_factory=no_nodes)

    def __post_init__(self) -> None:
        both = sorted(set(self.nodes.ids) & set(self.landmarks.ids))
        if both:
            raise ValueError(f"{both[0]!r} names both a node and a landmark; give the node another id")

    # -- CSV ---------------------------------------------------------------
    def to_csv(self) -> str:
        """Nodes, then landmarks (``kind`` column only when there are landmarks); counts and covariance columns when
        either set has them (a set without: empty cells)."""
        nodes, marks = self.nodes, self.landmarks
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

    @classmethod
    def from_csv(cls, text: str, source: str = "node file", kind: str = NODE) -> "NodeFile":
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
        return cls._split(source, kinds, ids, labels, np.array(xyz).reshape(-1, 3),
                          np.array(counts) if has_counts else None, frame=frame, comments=comments,
                          cov=np.array(covs).reshape(-1, 3, 3) if has_cov else None)

    @classmethod
    def _split(cls, source: str, kinds: list[str], ids, labels, xyz, counts=None, *, frame: str = "",
               comments=(), cov=None) -> "NodeFile":
        """The rows as nodes and landmarks by ``kinds`` (comments with the nodes, no counts for landmarks);
        NodeFileError naming ``source`` for a landmark given twice or rows that make no node set."""
        marks = [ids[k] for k, kind in enumerate(kinds) if kind == LANDMARK]
        twice = sorted({name for name in marks if marks.count(name) > 1})
        if twice:
            raise NodeFileError(f"{source}: landmark {twice[0]!r} is given twice; give each landmark once")
        try:
            every = NodeSet(ids, labels, xyz, counts, frame=frame, cov=cov)
        except ValueError as err:
            raise NodeFileError(f"{source}: {err}") from None
        is_mark = np.array([kind == LANDMARK for kind in kinds], dtype=bool)
        nodes, landmarks = every.subset(~is_mark), every.subset(is_mark)
        nodes.comments, landmarks.counts = list(comments), None
        return cls(nodes, landmarks)

    # -- 3D Slicer markups ---------------------------------------------------
    def to_slicer(self) -> dict:
        """A Slicer markups document: the nodes' fiducial list (our id as point label, our anatomical label as
        description) and, when there are landmarks, a second list named :data:`LANDMARK_LIST` (label = name).

        Positions are written as given with ``coordinateSystem`` LPS (DICOM patient space); counts have no place in
        the Slicer schema and are not written.
        """
        lists = [_slicer_list(self.nodes)] + ([_slicer_list(self.landmarks, LANDMARK_LIST)] if len(self.landmarks)
                                              else [])
        return {"@schema": SLICER_SCHEMA, "markups": lists}

    @classmethod
    def from_slicer(cls, doc: dict, source: str = "markups file", kind: str = NODE) -> "NodeFile":
        """Nodes from the first fiducial list not named for landmarks, landmarks from the lists named for them and
        from vocabulary labels (module docstring); each list's positions in LPS whichever system it says. ``kind``:
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
        return cls._split(source, kinds, ids, labels, np.array(xyz, dtype=float).reshape(-1, 3), frame="LPS")


def read_nodes(path: str | Path) -> NodeSet:
    """The nodes of a node CSV or a Slicer ``.mrk.json`` (its landmarks left out: :func:`read_node_file` gives both);
    :class:`NodeFileError` says what is wrong."""
    return read_node_file(path).nodes


def read_landmarks(path: str | Path) -> NodeSet:
    """A file of landmarks alone (a Slicer point list saved on its own, a CSV of landmark rows): every entry a landmark
    whatever its name; :class:`NodeFileError` when a CSV row says it is a node."""
    read = read_node_file(path, kind=LANDMARK)
    if len(read.nodes):
        what = "is a node" if len(read.nodes) == 1 else "are nodes"
        raise NodeFileError(f"{path}: {', '.join(read.nodes.ids[:3])} {what} (kind node); a landmark file holds "
                            "landmarks only")
    return read.landmarks


def read_node_file(path: str | Path, kind: str = NODE) -> NodeFile:
    """The nodes and landmarks of a node CSV or a Slicer ``.mrk.json`` (module docstring); ``kind``: what an entry
    is that does not say. :class:`NodeFileError` says what is wrong."""
    path = Path(path)
    text = read_text_file(path, "node", NodeFileError, max_bytes=MAX_NODE_FILE_BYTES)
    if path.name.lower().endswith(".json"):
        try:
            doc = json.loads(text)
        except RecursionError:
            raise NodeFileError(f"{path}: nested too deeply to be a 3D Slicer markups file") from None
        except ValueError as err:                 # JSONDecodeError, or an integer of more than 4300 digits
            raise NodeFileError(f"{path}: not valid JSON ({str(err).split(':')[0]})") from None
        return NodeFile.from_slicer(doc, str(path), kind)
    return NodeFile.from_csv(text, str(path), kind)


def write_nodes(nodes: NodeSet, path: str | Path, landmarks: NodeSet | None = None) -> None:
    """Write a node set, and ``landmarks`` apart when given, as CSV, or as Slicer markups when the name ends in
    ``.json``, atomically (``OSError`` if it cannot be written; the previous file then stays as it was)."""
    path = Path(path)
    written = NodeFile(nodes, no_nodes(nodes.frame) if landmarks is None else landmarks)
    text = json.dumps(written.to_slicer(), indent=2) if path.name.lower().endswith(".json") else written.to_csv()
    with atomic_write(path) as temporary:
        temporary.write_text(text, encoding="utf-8")


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
