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
pass :func:`snreg.landmarks.landmark_name`. The formats' text (columns, cells, point lists) is
:mod:`snreg.node_formats`'s; what a file holds, and reading and writing it, is here.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from snreg.errors import NodeFileError
from snreg.files import atomic_write, read_text_file
from snreg.landmarks import LANDMARK, NODE
from snreg.node_formats import NodeRows, csv_rows, csv_text, slicer_document, slicer_rows

__all__ = ["NodeSet", "NodeFile", "NodeFileError", "read_nodes", "read_node_file", "read_landmarks", "write_nodes",
           "no_nodes", "PREOP_PREFIX", "INTRAOP_PREFIX"]

# The ids snreg itself gives: preop nodes from a SPECT are P1, P2, ... (hottest first), intraop nodes stored in
# surgery SN1, SN2, ..., so "SN1 -> P3" cannot be misread. Ids read from a user's file may be anything.
PREOP_PREFIX = "P"
INTRAOP_PREFIX = "SN"

MAX_NODE_FILE_BYTES = 16 << 20        # a node file holds tens of nodes; 16 MB holds hundreds of thousands


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
        """Nodes, then landmarks, as node CSV (:func:`~snreg.node_formats.csv_text`)."""
        return csv_text(self.nodes, self.landmarks)

    @classmethod
    def from_csv(cls, text: str, source: str = "node file", kind: str = NODE) -> "NodeFile":
        """Parse a node CSV (:func:`~snreg.node_formats.csv_rows`); ``kind``: what a row is whose ``kind`` cell is
        empty or absent. NodeFileError in one sentence naming the file and the row."""
        return cls._split(source, csv_rows(text, source, kind))

    @classmethod
    def _split(cls, source: str, rows: NodeRows) -> "NodeFile":
        """The rows as nodes and landmarks by their kinds (comments with the nodes, no counts for landmarks);
        NodeFileError naming ``source`` for a landmark given twice or rows that make no node set."""
        marks = [rows.ids[k] for k, kind in enumerate(rows.kinds) if kind == LANDMARK]
        twice = sorted({name for name in marks if marks.count(name) > 1})
        if twice:
            raise NodeFileError(f"{source}: landmark {twice[0]!r} is given twice; give each landmark once")
        try:
            every = NodeSet(rows.ids, rows.labels, rows.xyz, rows.counts, frame=rows.frame, cov=rows.cov)
        except ValueError as err:
            raise NodeFileError(f"{source}: {err}") from None
        is_mark = np.array([kind == LANDMARK for kind in rows.kinds], dtype=bool)
        nodes, landmarks = every.subset(~is_mark), every.subset(is_mark)
        nodes.comments, landmarks.counts = list(rows.comments), None
        return cls(nodes, landmarks)

    # -- 3D Slicer markups ---------------------------------------------------
    def to_slicer(self) -> dict:
        """A Slicer markups document of the nodes and, in a list of their own, the landmarks
        (:func:`~snreg.node_formats.slicer_document`)."""
        return slicer_document(self.nodes, self.landmarks)

    @classmethod
    def from_slicer(cls, doc: dict, source: str = "markups file", kind: str = NODE) -> "NodeFile":
        """Nodes and landmarks of a Slicer markups document (:func:`~snreg.node_formats.slicer_rows`, module
        docstring); ``kind``: what a control point of the nodes' list is when its label is not a vocabulary name."""
        return cls._split(source, slicer_rows(doc, source, kind))


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
