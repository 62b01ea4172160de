"""The demo's preop files: the phantom's SPECT and its report of stations, written beside the session.

Why: both demos (``snreg demo --headless`` and ``snreg-gui --demo``) must ask the registration the same question, so
one function writes what a nuclear-medicine department would hand over: the SPECT as NM DICOM and the report naming
each hot spot's station (thesis Table 1), a ``snreg preop --stations`` table. With it the labels the technician types
("EXT L") pair on station as well as side.

>>> preop = write_phantom_preop(rig, "case.h5")     # case-spect.dcm and case-stations.csv beside case.h5
>>> preop.nodes.labels                              # ["EXT L", "OBT R", ...]: the SPECT segmented with its report
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from snreg.demo.phantom import spect_report, write_station_table
from snreg.demo.scene import NODE_CENTRES_MM
from snreg.nodes import NodeSet
from snreg.preop.segment import segment_nodes
from snreg.preop.volume import Volume, load_volume

N_NODES = len(NODE_CENTRES_MM)


def spect_path_for(session_path: str | Path) -> Path:
    """Where the demo writes the phantom's SPECT: beside the session, ``<name>-spect.dcm``."""
    session_path = Path(session_path)
    return session_path.with_name(session_path.stem + "-spect.dcm")


def stations_path_for(session_path: str | Path) -> Path:
    """Where the demo writes the SPECT's report of stations: beside the session, ``<name>-stations.csv`` (``snreg preop
    <name>-spect.dcm --stations <name>-stations.csv`` reads the preop nodes as the demo did)."""
    session_path = Path(session_path)
    return session_path.with_name(session_path.stem + "-stations.csv")


@dataclass(frozen=True)
class PhantomPreop:
    """The files written and what they give: the SPECT read back and its hot spots labelled with the report."""

    spect_path: Path
    stations_path: Path
    volume: Volume
    stations: dict[str, str]          # hot spot id -> station, as the report names them
    nodes: NodeSet                    # the SPECT segmented into the phantom's nodes with the report (LPS mm)


def write_phantom_preop(rig, session_path: str | Path) -> PhantomPreop:
    """Write ``rig``'s phantom SPECT (:meth:`~snreg.demo.rig.DemoRig.write_phantom_spect`) and its report of stations
    beside ``session_path``, segment the SPECT into the phantom's nodes and label them with the report."""
    sources = rig.phantom_sources_lps()
    spect = rig.write_phantom_spect(spect_path_for(session_path))
    volume = load_volume(spect)
    found = segment_nodes(volume, n_nodes=N_NODES).nodes
    # the SPECT as reported: each hot spot's station, as the labels typed at the stores name theirs
    stations = spect_report(found.ids, found.xyz, sources)
    table = write_station_table(stations_path_for(session_path), stations)
    nodes = segment_nodes(volume, n_nodes=N_NODES, stations=stations).nodes
    return PhantomPreop(Path(spect), table, volume, stations, nodes)
