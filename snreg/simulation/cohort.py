"""A synthetic cohort standing in for the thesis' 13 patient scans (thesis §3.3, Table 1).

The scans are not public, so node positions are drawn around pelvic lymph-node station
centres. Frame: DICOM patient coordinates (LPS: x to the patient's left, y posterior,
z superior), in mm, with the origin at the upper border of the pubic symphysis.

Where the positions come from: the station centres and spreads below are approximate
values for an adult male pelvis, read off the anatomy that the RTOG pelvic lymph-node
contouring atlas describes (Lawton et al., IJROBP 2009: external iliac along the pelvic
brim, obturator in the obturator fossa below it, internal iliac along the pelvic side
wall, common iliac up to the aortic bifurcation, presacral in front of S1-S3), and the
station frequencies follow the prostate sentinel-node maps (Joniau et al., Eur Urol
2013; Mattei et al., Eur Urol 2008: internal iliac, obturator and external iliac
dominate). They are plausible, not measured; a directory of real node CSVs replaces
them (:func:`load_cohort`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from snreg.nodes import PREOP_PREFIX, NodeSet, read_nodes

__all__ = ["Patient", "synthetic_cohort", "load_cohort", "THESIS_NODE_COUNTS", "STATION_CENTRES"]

THESIS_NODE_COUNTS = (3, 5, 4, 3, 6, 5, 7, 6, 5, 4, 5, 7, 5)   # thesis Table 1, "SN imaged"
COHORT_SEED = 20230601
MIN_SEPARATION_MM = 12.0  # closer nodes merge into one SPECT hot spot

# station: (centre of the right-side station (x < 0 is right in LPS), per-axis spread sigma, frequency)
STATION_CENTRES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float], float]] = {
    "EXT": ((-55.0, 20.0, 30.0), (6.0, 8.0, 15.0), 0.22),
    "OBT": ((-45.0, 40.0, 10.0), (6.0, 10.0, 10.0), 0.26),
    "INT": ((-45.0, 75.0, 45.0), (8.0, 10.0, 12.0), 0.26),
    "COM": ((-30.0, 70.0, 110.0), (8.0, 8.0, 12.0), 0.06),
    "BIF": ((-40.0, 70.0, 85.0), (6.0, 8.0, 8.0), 0.06),
    "SAC": ((-10.0, 100.0, 70.0), (6.0, 6.0, 15.0), 0.05),
    "PR": ((-20.0, 75.0, 15.0), (6.0, 8.0, 10.0), 0.05),
    "PVS": ((-30.0, 20.0, 0.0), (6.0, 8.0, 8.0), 0.04),
}


@dataclass(frozen=True)
class Patient:
    """One patient's preop nodes (the SPECT centres) with station labels."""

    name: str
    nodes: NodeSet


def _draw_node(rng: np.random.Generator) -> tuple[str, np.ndarray]:
    names = list(STATION_CENTRES)
    freq = np.array([STATION_CENTRES[s][2] for s in names])
    station = names[rng.choice(len(names), p=freq / freq.sum())]
    centre, spread, _ = STATION_CENTRES[station]
    side = "R" if rng.random() < 0.5 else "L"
    xyz = rng.normal(centre, spread)
    if side == "L":
        xyz[0] = -xyz[0]
    return f"{station} {side}", xyz


def synthetic_cohort(node_counts=THESIS_NODE_COUNTS, seed: int = COHORT_SEED) -> list[Patient]:
    """Patients with the given node counts, nodes at least MIN_SEPARATION_MM apart."""
    rng = np.random.default_rng(seed)
    patients = []
    for k, count in enumerate(node_counts):
        labels, points = [], []
        while len(points) < count:
            label, xyz = _draw_node(rng)
            if all(np.linalg.norm(xyz - p) >= MIN_SEPARATION_MM for p in points):
                labels.append(label)
                points.append(xyz)
        nodes = NodeSet.from_xyz(np.array(points), labels, prefix=PREOP_PREFIX, frame="LPS")
        patients.append(Patient(f"P{k + 1:02d}", nodes))
    return patients


def load_cohort(directory: str | Path) -> list[Patient]:
    """Every ``*.csv`` node file in a directory as one patient (name from the file stem)."""
    files = sorted(Path(directory).glob("*.csv"))
    if not files:
        raise ValueError(f"{directory}: no node CSV files found for a cohort")
    patients = []
    for path in files:
        nodes = read_nodes(path)
        if len(nodes) < 3:
            raise ValueError(f"{path}: a patient needs at least 3 nodes to register; found {len(nodes)}")
        patients.append(Patient(path.stem, nodes))
    return patients
