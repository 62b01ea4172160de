"""What the preop box's workers run: read a node file, load and segment a SPECT, read a station table (no Qt).

Why apart from :mod:`snreg_gui.registration.preop`: these run in worker threads and touch no widget; each returns a
:class:`PreopRead` stamped with the box's generation, so a result made for an older file or older settings is
dropped, and with the stations it was segmented with, so the labels shown and the status always agree.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from snreg.nodes import NodeSet, read_node_file
from snreg.preop import Volume, load_volume, read_station_table, segment_nodes
from snreg.preop.gravity import PreopDown, volume_down

NODE_FILE_SUFFIXES = (".csv", ".json", ".txt")


@dataclass(frozen=True)
class PreopRead:
    """The outcome of one read or segmentation: nodes, the volume they came from (None for a node file), the node
    file's landmarks (None for a SPECT or a file without any), and what gives their down: the SPECT's patient position,
    or the one a node file's comments record (None: none recorded); ``stations`` the SPECT's hot spots were labelled
    with (None: sides only) and the table's name."""

    generation: int
    nodes: NodeSet
    volume: Volume | None
    source: str
    landmarks: NodeSet | None = None
    down: PreopDown | None = None
    stations: dict[str, str] | None = None
    stations_source: str = ""


def read_preop(generation: int, path: str, threshold: float, n_nodes: int | None,
               stations_path: str | None = None) -> PreopRead:
    """Read a node file, or load a SPECT (NM) volume and segment it, with the station table at ``stations_path`` when
    given (worker thread)."""
    location = Path(path)
    if not location.exists():
        raise ValueError(f"{location}: no such file or folder; choose a node file or a SPECT DICOM file or folder")
    if location.is_file() and location.name.lower().endswith(NODE_FILE_SUFFIXES):
        if stations_path is not None:
            raise ValueError(f"{location.name} is a node file, which carries its own labels: a station table labels "
                             "the hot spots of a SPECT")
        read = read_node_file(location)
        return PreopRead(generation, read.nodes, None, location.name,
                         read.landmarks if len(read.landmarks) else None,
                         PreopDown.from_comments(read.nodes.comments, location.name))
    stations = None if stations_path is None else read_station_table(stations_path)
    volume = load_volume(location, modality="NM")
    return segment(generation, volume, threshold, n_nodes, location.name, stations,
                   "" if stations_path is None else Path(stations_path).name)


def read_stations(generation: int, path: str, volume: Volume, threshold: float, n_nodes: int | None,
                  source: str) -> PreopRead:
    """Read the station table at ``path`` and segment the loaded ``volume`` with it (worker thread)."""
    return segment(generation, volume, threshold, n_nodes, source, read_station_table(path), Path(path).name)


def segment(generation: int, volume: Volume, threshold: float, n_nodes: int | None, source: str,
            stations: dict[str, str] | None = None, stations_source: str = "") -> PreopRead:
    """Segment an already loaded volume (worker thread), its hot spots labelled with ``stations`` when given; its
    down from its Patient Position (snreg's default tilt)."""
    nodes = segment_nodes(volume, threshold=threshold, n_nodes=n_nodes, stations=stations).nodes
    return PreopRead(generation, nodes, volume, source, down=volume_down(volume), stations=stations,
                     stations_source=stations_source if stations is not None else "")
