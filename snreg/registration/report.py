"""What a registration leaves behind for the record: the pairing table, the mapped preop nodes and a PNG report.

Why: the technician exports the outcome of the registration panel (pairing CSV, a 3D Slicer fiducial list of
the preop nodes in the intraop frame, a one-page figure), and offline review must be able to make the same
files without a window. Everything here is Qt-free; the figure is drawn with matplotlib's Agg canvas on a
``Figure`` object (no pyplot, so no global backend state and safe in a worker thread).

>>> rows = pair_rows(preop, intraop, result)          # one PairRow per intraop node: its hot spot, who shares it
>>> write_pairs_csv("pairs.csv", preop, intraop, result)
>>> write_nodes(mapped_preop(preop, result), "preop_in_trocar.mrk.json")
>>> save_report_png("report.png", preop, intraop, result, context=ReportContext(case_id="phantom-01"))
...                                                    # 1200 px wide, and report.json beside it
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from snreg import geometry
from snreg.nodes import NodeSet
from snreg.registration import CONFIDENT, RegistrationResult
from snreg.registration.report_meta import ReportContext, header_lines, png_text_chunks, report_metadata, sidecar_path
from snreg.registration.wording import confidence_text, confidence_value, rule_words
from snreg.tracking.uncertainty import ELLIPSOID_SCALE

__all__ = ["PairRow", "MissingNode", "missing_nodes", "pair_table", "pair_rows", "mapped_preop", "summary_line",
           "node_warnings", "pair_expected_mm", "write_pairs_csv", "registration_figure", "save_report_png",
           "NO_HOT_SPOT", "FAR_NODE_MM",
           "VIEWS", "REPORT_SIZE_IN", "REPORT_DPI"]

NO_HOT_SPOT = "none"            # shown instead of a preop id for a node from no imaged hot spot (pairing -1)
FAR_NODE_MM = 20.0              # a paired node farther than this from its mapped partner is warned about
# The three orthogonal projections of the trocar frame (name, horizontal axis, vertical axis): looking along its
# z axis (the endoscope's axis in the reference pose) shows x-y, along y shows x-z, along x shows y-z. Not
# axial/coronal/sagittal: the trocar frame is not the patient's.
VIEWS = (("along z", 0, 1), ("along y", 0, 2), ("along x", 1, 2))
REPORT_SIZE_IN = (12.0, 8.0)    # width; the height follows the content (about 8 in for a handful of nodes)
_HEADER_LINE_IN, _VIEWS_IN, _ROW_IN = 0.24, 3.4, 0.24
REPORT_DPI = 100
_UNIT_DRAWS = np.random.default_rng(0).standard_normal((20000, 3))   # for quantiles of an error's length
PREOP_COLOUR, INTRAOP_COLOUR, PAIR_COLOUR, DOUBT_COLOUR = "#1f77b4", "#d62728", "#7f7f7f", "#fdd0a2"
_CSV_COLUMNS = ("intraop_id", "intraop_label", "hot_spot", "hot_spot_label", "shared_with", "distance_mm", "confidence",
                "confident")


@dataclass(frozen=True)
class PairRow:
    """One intraop node and the hot spot it came from: ``preop_index`` into the preop set, -1 for a node from no
    imaged hot spot, whose ``preop_id`` is then :data:`NO_HOT_SPOT` and ``preop_label`` empty (screens, CSV) and null
    in JSON; ``shared_with``: the other intraop nodes that came from the same hot spot."""

    intraop_id: str
    intraop_label: str
    preop_index: int
    preop_id: str
    preop_label: str
    distance_mm: float
    confidence: float
    leave_one_out_mm: float = float("nan")   # its distance when the other pairs alone register; NaN if not paired
    shared_with: tuple[str, ...] = ()

    @property
    def paired(self) -> bool:
        return self.preop_index >= 0

    @property
    def confident(self) -> bool:
        return self.confidence >= CONFIDENT

    def as_json(self) -> dict:
        """The row for JSON output (``snreg register --json``): a node from no hot spot has ``preop_id`` and
        ``preop_label`` null."""
        return {"id": self.intraop_id, "label": self.intraop_label,
                "preop_id": self.preop_id if self.paired else None, "preop_label": self.preop_label if self.paired else None,
                "shared_with": list(self.shared_with),
                "distance_mm": round(self.distance_mm, 3), "confidence": confidence_value(self.confidence),
                "confident": self.confident,
                "leave_one_out_mm": None if np.isnan(self.leave_one_out_mm) else round(self.leave_one_out_mm, 3)}


def pair_table(result: RegistrationResult, preop_ids, intraop_ids, preop_labels=None,
               intraop_labels=None) -> list[PairRow]:
    """One :class:`PairRow` per intraop node, in intraop order: the one place a pairing becomes a table.

    ``preop_ids``/``intraop_ids`` (and the labels, "" when None) name the node sets the registration was run on;
    ValueError when they cannot be (too few or too many names).
    """
    pairing = np.asarray(result.pairing, dtype=int)
    if len(pairing) != len(intraop_ids):
        raise ValueError(f"the result pairs {len(pairing)} intraop nodes but {len(intraop_ids)} were given; "
                         "use the node sets the registration was run on")
    if len(pairing) and int(np.max(pairing)) >= len(preop_ids):
        raise ValueError(f"the result refers to preop node {int(np.max(pairing)) + 1} but only "
                         f"{len(preop_ids)} were given; use the node sets the registration was run on")
    preop_labels = preop_labels if preop_labels is not None else [""] * len(preop_ids)
    intraop_labels = intraop_labels if intraop_labels is not None else [""] * len(intraop_ids)
    loo = result.leave_one_out_mm if result.leave_one_out_mm is not None else np.full(len(pairing), np.nan)
    rows = []
    for m, n in enumerate(pairing):
        preop_id, preop_label = (NO_HOT_SPOT, "") if n < 0 else (preop_ids[n], preop_labels[n])
        others = () if n < 0 else tuple(intraop_ids[k] for k in np.flatnonzero(pairing == n) if k != m)
        rows.append(PairRow(intraop_ids[m], intraop_labels[m], int(n), preop_id, preop_label,
                            float(result.distances_mm[m]), float(result.confidence[m]), float(loo[m]), others))
    return rows


@dataclass(frozen=True)
class MissingNode:
    """A preop node with no intraop partner: where the registration maps it (trocar frame, mm) and the 90% bound
    on how far from there it really is."""

    preop_index: int
    preop_id: str
    preop_label: str
    mapped_xyz: np.ndarray
    bound_mm: float

    def as_json(self) -> dict:
        return {"preop_id": self.preop_id, "preop_label": self.preop_label,
                "mapped_xyz": [round(float(v), 3) for v in self.mapped_xyz], "target_error_mm": round(self.bound_mm, 3)}


def missing_nodes(preop: NodeSet, result: RegistrationResult) -> list[MissingNode]:
    """The preop nodes the registration left unpaired (not removed yet, or never found), in preop order."""
    if result.missing is None:
        return []
    mapped = geometry.apply(result.transform, preop.xyz)
    bounds = result.target_error_mm if result.target_error_mm is not None else np.full(len(preop), np.nan)
    return [MissingNode(k, preop.ids[k], preop.labels[k], mapped[k], float(bounds[k]))
            for k in np.flatnonzero(result.missing)]


def pair_rows(preop: NodeSet, intraop: NodeSet, result: RegistrationResult) -> list[PairRow]:
    """:func:`pair_table` of the node sets the registration was run on."""
    return pair_table(result, preop.ids, intraop.ids, preop.labels, intraop.labels)


def mapped_preop(preop: NodeSet, result: RegistrationResult) -> NodeSet:
    """The preop nodes moved into the intraop (trocar) frame by ``result.transform``, ids and labels kept, each hot
    spot's covariance turned with them."""
    return preop.moved(result.transform, "trocar",
                       [f"preop nodes mapped by a {result.method} registration (RMS {result.rms_mm:.2f} mm)"])


def pair_expected_mm(intraop: NodeSet, result: RegistrationResult, level: float = 0.9) -> np.ndarray:
    """(M,) mm per intraop node: the ``level`` quantile (90 % bound; 0.5: its typical value) of its distance from its
    hot spot's mapped position, were its claim
    right and the node left out of the fit (its leave-one-out distance is the figure to compare; its distance within
    the fit is smaller, the fit leaning towards it). The pair's error is modelled as the node's own covariance (when
    every stored node has one: the registration then weighed them by it) plus the hot spot's expected error, taken as
    isotropic with the 90 % radius T of ``result.target_error_mm`` (the fit's error there, the hot spot's own and the
    unmodelled error: T / 2.50 per axis); the bound is the 90th percentile of that error's length. Without the nodes'
    covariances it is T itself at 90 % (T then holds the one error all nodes share; another ``level``: that error's
    quantile). NaN for a node from no hot spot, or without target errors."""
    expected = np.full(len(intraop), np.nan)
    if result.target_error_mm is None:
        return expected
    covariances = intraop.known_cov
    for m, n in enumerate(np.asarray(result.pairing, dtype=int)[: len(intraop)]):
        if n >= 0:
            spot = (result.target_error_mm[n] / ELLIPSOID_SCALE) ** 2 * np.eye(3)
            own = np.zeros((3, 3)) if covariances is None else covariances[m]
            expected[m] = (result.target_error_mm[n] if covariances is None and level == 0.9
                           else _length_quantile(own + spot, level))
    return expected


def _length_quantile(covariance: np.ndarray, level: float = 0.9) -> float:
    """The ``level`` quantile (mm) of the length of a zero-mean Gaussian error of ``covariance`` (3, 3) mm^2, from
    fixed standard normal draws (deterministic; its length depends on the eigenvalues alone)."""
    variances = np.maximum(np.linalg.eigvalsh(covariance), 0.0)
    return float(np.quantile(np.sqrt(_UNIT_DRAWS**2 @ variances), level))


def write_pairs_csv(path, preop: NodeSet, intraop: NodeSet, result: RegistrationResult) -> Path:
    """The pairing table as CSV (``#`` comment lines: method, RMS, transform), one row per intraop node: its hot spot
    (empty for none), the other nodes from the same hot spot (space-separated), distance and confidence."""
    rows = pair_rows(preop, intraop, result)
    path = Path(path)
    transform = " ".join(f"{v:.6g}" for v in np.asarray(result.transform).ravel())
    with path.open("w", newline="", encoding="utf-8") as handle:
        handle.write(f"# method: {result.method}\n# rms_mm: {result.rms_mm:.4f}\n"
                     f"# intraop_from_preop (row-major 4x4): {transform}\n")
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(_CSV_COLUMNS)
        for row in rows:
            writer.writerow([row.intraop_id, row.intraop_label, row.preop_id if row.paired else "", row.preop_label,
                             " ".join(row.shared_with), f"{row.distance_mm:.3f}", confidence_text(row.confidence, 4),
                             int(row.confident)])
    return path


def summary_line(result: RegistrationResult, rows: list[PairRow]) -> str:
    """One line: method, RMS, how many intraop nodes came from a hot spot, how many hot spots yielded several, and
    how many claims are confident."""
    paired = sum(row.paired for row in rows)
    confident = sum(row.confident for row in rows)
    shared = len({row.preop_index for row in rows if row.shared_with})
    several = f", {shared} hot spot{'s' if shared > 1 else ''} with several" if shared else ""
    return (f"{result.method}: RMS {result.rms_mm:.2f} mm, {paired} of {len(rows)} intraop nodes from a hot spot"
            f"{several}, {confident} confident (>= {CONFIDENT:g})")


def node_warnings(rows: list[PairRow], far_mm: float = FAR_NODE_MM) -> list[str]:
    """One plain sentence per intraop node to check: from a hot spot but farther than ``far_mm`` from its mapped
    position, or from no imaged hot spot, in intraop order.

    Why: a node 372 mm from every preop node was reported as "5 of 5 paired" by chamfer, with only a shaded row;
    a distance far beyond the tracking and SPECT errors means the pairing (or the stored node) is wrong, whatever
    the method's confidence says.
    """
    warnings = []
    for row in rows:
        if row.paired and row.distance_mm > far_mm:
            warnings.append(f"{row.intraop_id} is {row.distance_mm:.0f} mm from its hot spot {row.preop_id} "
                            f"(more than {far_mm:g} mm): check this pairing and the stored node")
        elif not row.paired:
            warnings.append(f"{row.intraop_id} came from no imaged hot spot (the nearest is {row.distance_mm:.0f} mm "
                            "away): a node not on the SPECT, or a mis-stored one; check it")
    return warnings


def registration_figure(preop: NodeSet, intraop: NodeSet, result: RegistrationResult, *, title: str = "",
                        meta: dict | None = None):
    """A matplotlib ``Figure``: a header, three projections of both sets in the trocar frame with the pairs, the
    pair table and the warnings, its height sized to that content (no blank band) at ``REPORT_SIZE_IN[0]`` wide.

    ``meta`` (:func:`~snreg.registration.report_meta.report_metadata`) gives the header lines (case, date,
    session, calibration, method, RMS, counts, version); without it the header is the summary line. Preop nodes
    are drawn after mapping by ``result.transform`` (blue circles), intraop nodes as red crosses, pairs as grey
    lines; rows whose confidence is below ``CONFIDENT`` are shaded in the table.
    """
    from matplotlib.figure import Figure

    rows = pair_rows(preop, intraop, result)
    moved = geometry.apply(result.transform, preop.xyz)
    header = ([title] if title else []) + (header_lines(meta) if meta is not None else [summary_line(result, rows)])
    warnings = node_warnings(rows)
    # inches from the top: header, view titles, views, their axis labels and the table's title, table, warnings
    header_in = _HEADER_LINE_IN * len(header) + 0.2
    table_in = _ROW_IN * (len(rows) + 1)
    notes_in = _HEADER_LINE_IN * len(warnings) + 0.2
    height = header_in + 0.35 + _VIEWS_IN + 0.75 + table_in + notes_in
    figure = Figure(figsize=(REPORT_SIZE_IN[0], height), dpi=REPORT_DPI)
    for k, line in enumerate(header):
        figure.text(0.01, 1 - (0.1 + _HEADER_LINE_IN * (k + 0.8)) / height, line, fontsize=10 if k else 12,
                    weight="normal" if k else "bold")
    views_top = 1 - (header_in + 0.35) / height
    grid = figure.add_gridspec(1, 3, wspace=0.3, left=0.07, right=0.98, top=views_top,
                               bottom=views_top - _VIEWS_IN / height)
    for column, (name, h, v) in enumerate(VIEWS):
        ax = figure.add_subplot(grid[0, column])
        for m, n in enumerate(result.pairing):
            if n >= 0:
                ax.plot([intraop.xyz[m, h], moved[n, h]], [intraop.xyz[m, v], moved[n, v]], color=PAIR_COLOUR, lw=1)
        ax.scatter(moved[:, h], moved[:, v], s=60, facecolors="none", edgecolors=PREOP_COLOUR, linewidths=1.5,
                   label="preop (mapped)")
        ax.scatter(intraop.xyz[:, h], intraop.xyz[:, v], s=50, marker="x", color=INTRAOP_COLOUR, label="intraop")
        for k, node_id in enumerate(preop.ids):
            ax.annotate(node_id, moved[k, [h, v]], xytext=(4, 4), textcoords="offset points", fontsize=7,
                        color=PREOP_COLOUR)
        for k, node_id in enumerate(intraop.ids):
            ax.annotate(node_id, intraop.xyz[k, [h, v]], xytext=(4, -9), textcoords="offset points", fontsize=7,
                        color=INTRAOP_COLOUR)
        ax.set_title(f"{name} ({'xyz'[h]}-{'xyz'[v]}, trocar frame)", fontsize=10)
        ax.set_xlabel(f"{'xyz'[h]} trocar (mm)")
        ax.set_ylabel(f"{'xyz'[v]} trocar (mm)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        if column == 0:
            ax.legend(fontsize=7, loc="best")
    table_ax = figure.add_axes((0.07, (notes_in + 0.02) / height, 0.91, table_in / height))
    table_ax.axis("off")
    cells = [[r.intraop_id, r.intraop_label, r.preop_id, r.preop_label, " ".join(r.shared_with) or "-",
              f"{r.distance_mm:.1f}", confidence_text(r.confidence)] for r in rows]
    colours = [["white" if r.confident else DOUBT_COLOUR] * 7 for r in rows]
    if cells:
        table = table_ax.table(cellText=cells, cellColours=colours, cellLoc="center", bbox=(0.0, 0.0, 1.0, 1.0),
                               colLabels=["intraop id", "intraop label", "hot spot", "hot spot label", "with",
                                          "distance mm", "confidence"])
        table.auto_set_font_size(False)
        table.set_fontsize(9)
    table_ax.set_title(f"method {result.method} ({rule_words(result.pairing_rule)}), RMS {result.rms_mm:.2f} mm; "
                       f"shaded: confidence below {CONFIDENT:g}, printed rounded down", fontsize=9)
    for k, text in enumerate(warnings):
        figure.text(0.01, (notes_in - 0.1 - _HEADER_LINE_IN * (k + 0.8)) / height, f"WARNING: {text}",
                    fontsize=9, color=INTRAOP_COLOUR)
    return figure


def save_report_png(path, preop: NodeSet, intraop: NodeSet, result: RegistrationResult, *, title: str = "",
                    context: ReportContext | None = None, dpi: int = REPORT_DPI) -> Path:
    """Write :func:`registration_figure` as a PNG ``REPORT_SIZE_IN[0]`` x ``dpi`` pixels wide (1200 by default), as
    tall as its content, with :func:`~snreg.registration.report_meta.report_metadata` in its text chunks and in
    a sidecar JSON beside it (:func:`~snreg.registration.report_meta.sidecar_path`); returns the PNG's path."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    rows = pair_rows(preop, intraop, result)
    meta = report_metadata(result, rows, missing_nodes(preop, result), context, node_warnings(rows))
    figure = registration_figure(preop, intraop, result, title=title, meta=meta)
    FigureCanvasAgg(figure)
    path = Path(path)
    figure.savefig(path, dpi=dpi, format="png", metadata=png_text_chunks(meta))
    sidecar_path(path).write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return path
