"""Anatomical labels (``"OBT R"``) as pairing costs: side crossings forbidden, station mismatches penalised.

Stations follow thesis Fig. 6: BIF, SAC, COM, EXT, INT, PR, PVS, OBT, each L or R.
Labels are often revised during surgery (thesis Table 1 lists station changes in 11 of
13 patients), so a station mismatch is only a soft penalty; a left/right crossing is
practically forbidden (a large finite cost keeps every assignment problem solvable).
"""

from __future__ import annotations

import numpy as np

from snreg.landmarks import LANDMARKS     # the landmark vocabulary, defined with the rule its names pass

__all__ = ["parse_label", "label_cost", "SIDE_CROSSING_NATS", "STATION_MISMATCH_NATS", "STATIONS", "LANDMARKS"]

SIDE_CROSSING_NATS = 50.0
STATION_MISMATCH_NATS = 1.0

STATIONS = {
    "BIF": "BIF", "BIFR": "BIF", "BIFURCATION": "BIF",
    "SAC": "SAC", "PRESACRAL": "SAC",
    "COM": "COM", "CIA": "COM", "COMMON": "COM",
    "EXT": "EXT", "EIA": "EXT", "EXTERNAL": "EXT",
    "INT": "INT", "IIA": "INT", "INTERNAL": "INT",
    "PR": "PR", "PARARECTAL": "PR",
    "PVS": "PVS", "PARAVESICAL": "PVS",
    "OBT": "OBT", "OBTURATOR": "OBT",
}
_SIDES = {"L": "L", "LEFT": "L", "R": "R", "RIGHT": "R"}


def parse_label(label: str | None) -> tuple[str, str]:
    """(station, side) of a label such as ``"OBT R"`` or ``"left external iliac"``; "" where unknown."""
    station, side = "", ""
    for token in (label or "").replace("_", " ").replace("-", " ").upper().split():
        if token in _SIDES:
            side = _SIDES[token]
        elif token in STATIONS and not station:
            station = STATIONS[token]
    return station, side


def label_cost(preop_labels, intraop_labels, n_preop: int, n_intraop: int) -> np.ndarray:
    """(N, M) cost in nats of pairing preop n with intraop m according to their labels."""
    cost = np.zeros((n_preop, n_intraop))
    if preop_labels is None or intraop_labels is None:
        return cost
    pre = [parse_label(label) for label in preop_labels]
    intra = [parse_label(label) for label in intraop_labels]
    for n, (station_p, side_p) in enumerate(pre):
        for m, (station_i, side_i) in enumerate(intra):
            if side_p and side_i and side_p != side_i:
                cost[n, m] += SIDE_CROSSING_NATS
            if station_p and station_i and station_p != station_i:
                cost[n, m] += STATION_MISMATCH_NATS
    return cost
