"""Preop landmarks from a file of their own: a radiologist's point list placed on the CT, in the preop nodes' frame.

Why: the landmarks (e.g. the aortic bifurcation) are placed on the CT in 3D Slicer and saved apart from the SPECT's
hot spots, as a ``.mrk.json`` in RAS or LPS (or a CSV of landmark rows). The registration pairs them with the touched
ones by name in the preop nodes' frame, patient LPS (docs/design.md, Conventions), so a file's points must come out in LPS whatever it
was saved in, and one in any other frame (a trocar-frame file given by mistake) is refused rather than mixed in. The
app's "Landmarks..." button and ``snreg register --preop-landmarks`` read them the same way.

>>> marks = read_preop_landmarks("ct_landmarks.mrk.json")      # NodeSet, ids = names, frame "LPS", mm
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from snreg.errors import NodeFileError
from snreg.nodes import NodeSet, read_landmarks

__all__ = ["read_preop_landmarks", "PREOP_FRAMES"]

PREOP_FRAMES = ("", "LPS", "RAS")       # what a preop landmark file may say it is in ("": LPS, as node files are)


def read_preop_landmarks(path: str | Path) -> NodeSet:
    """The landmarks of a file of landmarks alone (:func:`~snreg.nodes.read_landmarks`: every entry a landmark, a
    CSV row of kind node refused, names as snreg keeps them), in patient LPS mm: a Slicer file's RAS points are
    converted by the reader, a CSV saying ``# frame: RAS`` here (x and y negated). :class:`NodeFileError` in one
    sentence for a file with no landmarks or in another frame."""
    name = Path(path).name
    marks = read_landmarks(path)
    if not len(marks):
        raise NodeFileError(f"{name}: holds no landmarks; place them on the CT in 3D Slicer and save the point list")
    frame = marks.frame.strip().upper()
    if frame not in PREOP_FRAMES:
        raise NodeFileError(f"{name}: its points are in the {marks.frame} frame; preop landmarks are placed on the CT "
                            "(patient LPS or RAS)")
    xyz = marks.xyz * np.array([-1.0, -1.0, 1.0]) if frame == "RAS" else marks.xyz
    return NodeSet(list(marks.ids), list(marks.labels), xyz, frame="LPS")
