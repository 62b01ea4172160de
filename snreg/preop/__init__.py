"""Preoperative nodes from SPECT/CT DICOM: volume loading with patient geometry, segmentation, centres.

``load_volume`` -> :class:`Volume` (voxels (Z, Y, X), 4x4 patient_from_index, LPS mm);
``segment_nodes`` -> :class:`PreopNodes` (a NodeSet in LPS mm plus peak/total counts).
"""

from snreg.preop.segment import PreopNodes, read_station_table, segment_nodes, side_labels
from snreg.preop.volume import PreopError, Volume, load_volume

__all__ = ["Volume", "PreopError", "load_volume", "PreopNodes", "segment_nodes", "read_station_table",
           "side_labels"]
