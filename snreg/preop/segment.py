"""Sentinel nodes from SPECT activity, as the thesis did by hand (§3.3, §5.4.1), automated.

A threshold relative to the maximum separates sentinel nodes from higher echelons; connected
components (scipy.ndimage.label, 26-connected) are the hot spots; a hot spot with several
peaks of the lightly smoothed activity is split by activity-weighted k-means started at those
peaks (the thesis used k-means for the centres). Centres are activity-weighted centroids in
LPS mm; nodes are sorted by total activity, the hottest first, and named ``P1``, ``P2``... (preop ids never
look like the intraop ``SN1``... stored in surgery, so a pairing "SN1 -> P3" cannot be misread).

Each centre carries its own covariance (issue 28, :func:`hot_spot_covariance`): the counts' noise in the centroid and
how far the hot spot spreads beyond a point source's image, so registration knows a centre of a few merged nodes is
less certain (along their line) than a lone node's.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from snreg.files import read_text_file
from snreg.labels import parse_label
from snreg.nodes import PREOP_PREFIX, NodeSet
from snreg.preop.volume import PreopError, Volume

__all__ = ["PreopNodes", "segment_nodes", "read_station_table", "side_labels", "hot_spot_covariance",
           "RESOLUTION_MM"]

KMEANS_ITERATIONS = 30
MAX_NODES = 100          # more peaks than this above the threshold: the threshold is in the noise, not the nodes
RESOLUTION_MM = 12.0     # the scanner's resolution, FWHM of a point source (docs/design.md, Contracts: SPECT resolves about 10-15 mm)
_FWHM_PER_SD = 2.0 * np.sqrt(2.0 * np.log(2.0))
EXTENT_NOISE_SDS = 2.0   # a hot spot's extent counts where it stands this many sds of its counts' noise out


@dataclass(frozen=True)
class PreopNodes:
    """Segmented nodes: the NodeSet (LPS mm, counts = total activity) and per-node details.

    peak_counts, total_counts (N,) in the volume's real units; threshold in the same units;
    clusters (Z, Y, X) int32: 0 outside, k + 1 for the voxels of node k. ``nodes.cov`` (N, 3, 3) LPS mm^2: each
    centre's own covariance (:func:`hot_spot_covariance`).
    """

    nodes: NodeSet
    peak_counts: np.ndarray
    total_counts: np.ndarray
    threshold: float
    clusters: np.ndarray


def segment_nodes(volume: Volume, *, threshold: float = 0.3, n_nodes: int | None = None,
                  smoothing_mm: float = 3.0, min_separation_mm: float = 10.0,
                  midline_x: float | None = None, stations: dict[str, str] | None = None,
                  resolution_mm: float = RESOLUTION_MM) -> PreopNodes:
    """Nodes in ``volume`` above ``threshold`` x its maximum activity, each with its covariance for a scanner of
    ``resolution_mm`` (FWHM).

    ``n_nodes`` asks for exactly that many: the hot spots with the highest peaks are kept and,
    if too few, merged hot spots are split further. Peaks closer than ``min_separation_mm``
    count as one node (pelvic nodes closer than ~10 mm merge at SPECT resolution).
    Labels: side from x against ``midline_x`` (default the volume centre; LPS +x is the
    patient's left) and a station from ``stations`` (node id -> station, ids ``P1``...) when given; a station
    for an id that is not among the nodes found is a :class:`PreopError` (it would silently label nothing).
    """
    if not 0.0 < threshold < 1.0:
        raise PreopError(f"the threshold is relative to the maximum and must lie between 0 and 1, not {threshold:g}")
    if n_nodes is not None and not 1 <= n_nodes <= MAX_NODES:
        raise PreopError(f"the number of nodes must be at least 1 and at most {MAX_NODES}, not {n_nodes}")
    if not (np.isfinite(resolution_mm) and 0.0 < resolution_mm <= 100.0):
        raise PreopError(f"the scanner's resolution (FWHM) must be a number of mm above 0 and at most 100, not "
                         f"{resolution_mm:g}")
    voxels = volume.voxels
    peak_value = float(voxels.max()) if voxels.size else 0.0
    if not np.isfinite(peak_value) or peak_value <= 0 or float(voxels.min()) >= peak_value:
        raise PreopError("the volume has no activity above its background: nothing to segment")
    level = threshold * peak_value
    mask = voxels > level
    components, n_components = ndimage.label(mask, structure=np.ones((3, 3, 3)))
    spacing_zyx = volume.spacing_mm[::-1]
    smooth = ndimage.gaussian_filter(voxels, sigma=smoothing_mm / spacing_zyx)
    seeds = _seeds(smooth, mask, components, n_components, spacing_zyx, min_separation_mm)
    if n_nodes is not None:
        seeds = _choose(seeds, smooth, n_nodes, components, spacing_zyx, min_separation_mm)
    found = sum(len(chosen) for chosen in seeds.values())
    if found > MAX_NODES:
        raise PreopError(f"the threshold {threshold:g} x maximum selects {int(mask.sum())} voxels in {n_components} hot "
                         f"spot(s) with {found} peaks: more than the {MAX_NODES} nodes a SPECT of sentinel nodes "
                         "shows; raise --threshold (0.3 is usual) or give --nodes")
    clusters = np.zeros(voxels.shape, dtype=np.int32)
    centres, peaks, totals, covariances = [], [], [], []
    voxels_of = _component_voxels(components, list(seeds))
    for component, component_seeds in seeds.items():
        index = voxels_of[component]
        weight = voxels[tuple(index.T)] - level      # zero at the mask edge: the cut-off adds no bias
        assignment = _kmeans(index * spacing_zyx, weight, component_seeds, spacing_zyx)
        for k in range(len(component_seeds)):
            own = assignment == k
            if not own.any():
                continue
            centres.append(np.average(index[own], axis=0, weights=weight[own] + 1e-12))
            values = voxels[tuple(index[own].T)]
            peaks.append(float(values.max()))
            totals.append(float(values.sum()))
            clusters[tuple(index[own].T)] = len(centres)
            covariances.append(hot_spot_covariance(volume.patient_xyz(index[own]), values, level,
                                                   resolution_mm=resolution_mm,
                                                   voxel_axes_mm=volume.patient_from_index[:3, :3]))
    order = np.argsort(totals, kind="stable")[::-1]
    relabel = np.zeros(len(order) + 1, dtype=np.int32)
    relabel[order + 1] = np.arange(1, len(order) + 1)
    xyz = volume.patient_xyz(np.array(centres)[order])
    ids = [f"{PREOP_PREFIX}{k + 1}" for k in range(len(order))]
    unknown = sorted(set(stations or {}) - set(ids))
    if unknown:
        raise PreopError(f"the station table names {', '.join(unknown)}, but the nodes found are {ids[0]} to "
                         f"{ids[-1]} (hottest first); name them so, or change the threshold or node count")
    if midline_x is None:
        midline_x = float(volume.patient_xyz((np.array(voxels.shape) - 1) / 2)[0, 0])
    labels = side_labels(xyz, midline_x, ids, stations)
    totals_sorted = np.array(totals)[order]
    nodes = NodeSet(ids, labels, xyz, totals_sorted, frame="LPS", cov=np.array(covariances).reshape(-1, 3, 3)[order])
    return PreopNodes(nodes, np.array(peaks)[order], totals_sorted, level, relabel[clusters])


def hot_spot_covariance(positions, values, level: float, *, resolution_mm: float = RESOLUTION_MM,
                        voxel_axes_mm=None) -> np.ndarray:
    """(3, 3) mm^2: the covariance of a hot spot's centre, the centroid of its voxels at ``positions`` (n, 3) mm with
    ``values`` (n,) above ``level``, weighted by ``values - level`` as :func:`segment_nodes` weighs them;
    ``voxel_axes_mm`` (3, 3): a voxel's edges in mm as columns (the volume's ``patient_from_index``; None: 1 mm cubes).

    Two parts. The counts' noise: the voxel values taken as counts (Poisson, variance = value; reconstructed NM
    counts), each moves the centroid by its weight's share, ``sum v_i d_i d_i^T / W^2`` with d_i from the centre and
    W the weights' sum (on synthetic SPECTs of the thesis' 4.795 mm voxels and 141 peak counts it predicts the
    0.21 mm per axis found). And the hot spot's extent beyond a point source's: the weighted second moment of its
    voxels less the one a point at the centre would give on the same voxels, its positive part. The point is the
    scanner's blur (``resolution_mm`` FWHM, widened by the voxel's own box, an edge's square over 12) scaled to the
    values by least squares and cut at the same level, so the grid's sampling and the cut cancel; along each axis of
    the difference only what stands ``EXTENT_NOISE_SDS`` sds of the counts' noise out counts (noise alone would give
    every lone node some), and the cut's shrinking of second moments is undone by the factor it shrinks the point's
    blur by. The extent is zero for a lone node and about ``d^2 / 4`` along the line of two nodes ``d`` apart merged
    into one hot spot: where a node from it may lie. The grid's own sampling bias is left out (0.06 mm per axis at
    2000 peak counts). On 60 synthetic SPECTs of three lone sources at 141 peak counts the 90 % ellipsoids held 92 % of
    the centres (0.28 mm predicted, 0.21 mm found per axis).
    """
    positions = np.asarray(positions, float).reshape(-1, 3)
    values = np.asarray(values, float).reshape(-1)
    weight = values - level
    total = float(weight.sum())
    centre = weight @ positions / total
    offsets = positions - centre
    counting = np.einsum("n,ni,nj->ij", np.maximum(values, 0.0), offsets, offsets) / total**2
    spread = np.einsum("n,ni,nj->ij", weight, offsets, offsets) / total
    edges = np.eye(3) if voxel_axes_mm is None else np.asarray(voxel_axes_mm, float).reshape(3, 3)
    blur = (resolution_mm / _FWHM_PER_SD) ** 2 * np.eye(3) + edges @ edges.T / 12.0
    shape = np.exp(-0.5 * np.einsum("ni,ij,nj->n", offsets, np.linalg.inv(blur), offsets))
    point = np.maximum((values @ shape) / (shape @ shape) * shape - level, 0.0)
    own = np.einsum("n,ni,nj->ij", point, offsets, offsets) / max(float(point.sum()), 1e-300)
    eigen, vectors = np.linalg.eigh(spread - own)
    along = (offsets @ vectors) ** 2                               # (n, 3): each voxel's square along each axis
    noise = np.sqrt(np.maximum(values, 0.0) @ (along - along.T @ weight / total) ** 2) / total
    shrink = np.einsum("ia,ij,ja->a", vectors, own, vectors) / np.einsum("ia,ij,ja->a", vectors, blur, vectors)
    extent = np.maximum(eigen - EXTENT_NOISE_SDS * noise, 0.0) / np.maximum(shrink, 1e-3)
    return counting + (vectors * extent) @ vectors.T


def side_labels(xyz, midline_x: float, ids, stations: dict[str, str] | None = None) -> list[str]:
    """Labels like ``"OBT L"``: L where x > ``midline_x`` (LPS: +x is the patient's left), else R."""
    stations = stations or {}
    sides = ["L" if x > midline_x else "R" for x in np.asarray(xyz, float).reshape(-1, 3)[:, 0]]
    return [f"{stations.get(i, '')} {side}".strip() for i, side in zip(ids, sides)]


def read_station_table(path) -> dict[str, str]:
    """Node id -> station code (e.g. ``{"P1": "OBT"}``) from a CSV with columns ``id,station``."""
    path = Path(path)
    text = read_text_file(path, "station table", PreopError, max_bytes=1 << 20)
    try:
        rows = list(csv.DictReader(line for line in text.splitlines()
                                   if line.strip() and not line.lstrip().startswith("#")))
    except csv.Error as err:
        raise PreopError(f"{path}: not a readable station table ({err})") from None
    if not rows or not {"id", "station"} <= {k.strip().lower() for k in rows[0]}:
        raise PreopError(f"{path}: a station table needs a header 'id,station' and one row per node")
    table = {}
    for row in rows:
        row = {k.strip().lower(): (v or "").strip() for k, v in row.items() if isinstance(k, str) and not isinstance(v, list)}
        station, _ = parse_label(row["station"])
        if not station:
            raise PreopError(f"{path}: '{row['station']}' for {row['id']} is not a known station "
                             "(BIF, SAC, COM, EXT, INT, PR, PVS, OBT)")
        table[row["id"]] = station
    return table


def _seeds(smooth, mask, components, n_components, spacing_zyx, min_separation_mm) -> dict[int, list]:
    """Per component (1..n): its peaks (voxel indices), strongest first, at least min_separation_mm apart.

    Linear in the number of candidate peaks: chosen peaks are kept in a grid of cells ``min_separation_mm`` wide, so a
    candidate is compared with the few chosen in the 27 cells around it, not with all of them."""
    local_max = (smooth == ndimage.maximum_filter(smooth, size=3)) & mask
    candidates = np.argwhere(local_max)
    values = smooth[tuple(candidates.T)]
    seeds: dict[int, list] = {c: [] for c in range(1, n_components + 1)}
    cell_mm = max(float(min_separation_mm), 1e-9)
    grid: dict[tuple, list] = {}
    offsets = [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)]
    for k in np.argsort(values, kind="stable")[::-1]:
        peak = candidates[k]
        component = int(components[tuple(peak)])
        position = peak * spacing_zyx
        cell = tuple(int(v) for v in np.floor(position / cell_mm))
        near = (other for d in offsets for other in grid.get((component, cell[0] + d[0], cell[1] + d[1], cell[2] + d[2]), ()))
        if all(np.linalg.norm(position - other) >= min_separation_mm for other in near):
            seeds[component].append(peak)
            grid.setdefault((component, *cell), []).append(position)
    empty = [c for c, chosen in seeds.items() if not chosen]     # a plateau-free component still has its maximum
    if empty:
        for component, where in zip(empty, ndimage.maximum_position(smooth, components, empty)):
            seeds[component].append(np.array(where))
    return seeds


def _component_voxels(components: np.ndarray, wanted) -> dict[int, np.ndarray]:
    """Voxel indices (n, 3) of each wanted component, found in one pass (not one full scan per component)."""
    flat = components.ravel()
    inside = np.flatnonzero(flat)
    order = inside[np.argsort(flat[inside], kind="stable")]
    labels, starts = np.unique(flat[order], return_index=True)
    bounds = dict(zip(labels.tolist(), zip(starts, list(starts[1:]) + [len(order)])))
    return {c: np.stack(np.unravel_index(order[slice(*bounds[c])], components.shape), axis=1) for c in wanted}


def _choose(seeds: dict[int, list], smooth, n_nodes: int, components, spacing_zyx,
            min_separation_mm: float) -> dict[int, list]:
    """At most n_nodes seeds: components ranked by their top peak, extra peaks by height.

    When peaks run out (nodes merged beyond a visible dip), the component with the most voxels
    per seed gets a new seed at its voxel farthest from its seeds, for k-means to refine. A new
    seed must lie ``min_separation_mm`` from the others, as peaks must: asking for more nodes than
    fit that way is a :class:`PreopError` (it would cut hot spots into one-voxel "nodes").
    """
    height = {c: float(smooth[tuple(s[0])]) for c, s in seeds.items()}
    kept = sorted(seeds, key=lambda c: -height[c])[:n_nodes]
    chosen = {c: [seeds[c][0]] for c in kept}
    extras = sorted(((float(smooth[tuple(p)]), c, i) for c in kept for i, p in enumerate(seeds[c][1:], 1)),
                    key=lambda e: -e[0])
    for _, component, i in extras[:n_nodes - len(kept)]:
        chosen[component].append(seeds[component][i])
    counts = np.bincount(components.ravel())
    size = {c: int(counts[c]) for c in chosen}
    full: set[int] = set()
    while sum(len(s) for s in chosen.values()) < n_nodes:
        open_components = [c for c in chosen if c not in full]
        if not open_components:
            found = sum(len(s) for s in chosen.values())
            raise PreopError(f"only {found} node(s) at least {min_separation_mm:g} mm apart lie above the threshold, "
                             f"not the {n_nodes} asked for; ask for at most {found} (--nodes) or lower the threshold")
        component = max(open_components, key=lambda c: size[c] / len(chosen[c]))
        index = np.argwhere(components == component)
        gap = np.min([np.linalg.norm((index - s) * spacing_zyx, axis=1) for s in chosen[component]], axis=0)
        if gap.max() < min_separation_mm:
            full.add(component)
            continue
        chosen[component].append(index[np.argmax(gap)])
    return chosen


def _kmeans(points_mm, weight, seeds, spacing_zyx) -> np.ndarray:
    """(P,) cluster of each point: activity-weighted Lloyd iterations from the seed voxels (deterministic); each
    iteration is one nearest-centre query (``cKDTree``) and weighted sums (``bincount``), linear in the points."""
    centres = np.array(seeds, float) * spacing_zyx
    if len(centres) == 1:
        return np.zeros(len(points_mm), dtype=int)
    w = weight + 1e-12
    for _ in range(KMEANS_ITERATIONS):
        assignment = cKDTree(centres).query(points_mm)[1]
        mass = np.bincount(assignment, weights=w, minlength=len(centres))
        sums = np.stack([np.bincount(assignment, weights=w * points_mm[:, a], minlength=len(centres))
                         for a in range(3)], axis=1)
        updated = np.where(mass[:, None] > 0, sums / np.maximum(mass, 1e-300)[:, None], centres)
        if np.allclose(updated, centres, atol=1e-3):
            break
        centres = updated
    return assignment
