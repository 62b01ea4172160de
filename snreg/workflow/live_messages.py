"""The OpenIGTLink messages of the live link to 3D Slicer (docs/design.md, Contracts "Live link"), packed with pyigtl.

Why a module of its own: what goes over the wire (device names, frames, RAS versus LPS, units) is the contract
Slicer and outside checks rely on; :mod:`snreg.workflow.live_link` only moves these bytes. Each function returns
one packed message (header and body, CRC included) ready for a socket; :class:`StreamHealth` words the ``Status``
line's stream health.

How SlicerOpenIGTLink shows them (vtkMRMLIGTLConnectorNode, checked in its source): a TRANSFORM becomes a linear
transform node named after the device whose matrix is its "transform to parent", taken as sent; a POINT message
becomes a markups fiducial node whose control points are replaced by the list (labels = point names; a point whose
alpha is 0 is hidden; a message without points is dropped, see :func:`point_list`); a STRING becomes a text node.
Nothing is converted between LPS and RAS on the way, so the sender says which frame each device is in:

- ``ProbeTipToTrocar`` (TRANSFORM): probe to trocar, mm: the tip at the origin, z along the probe from the tip
  backwards (:func:`snreg.chain.camera_from_probe`).
- ``IntraopNodes`` (POINT): every stored node, trocar frame, mm, names = node ids.
- ``PreopNodes`` (POINT): the preop nodes in RAS, i.e. patient LPS with x and y negated, names = preop ids.
- ``IntraopLandmarks`` (POINT): every stored anatomical landmark, trocar frame, mm, names = landmark names.
- ``PreopLandmarks`` (POINT): the preop landmarks in RAS as ``PreopNodes``, names = landmark names.
- ``TrocarToRas`` (TRANSFORM): ``ras_from_lps @ inverse(intraop_from_preop)`` of the current registration; with
  ``ProbeTipToTrocar``, ``IntraopNodes`` and ``IntraopLandmarks`` under it, the probe and the stored points appear
  over the SPECT.
- ``Status`` (STRING): stream health and the last action, in words.
"""

from __future__ import annotations

import time

import numpy as np
import pyigtl

from snreg.geometry import invert

__all__ = ["DEFAULT_PORT", "PROBE_POSE", "INTRAOP_NODES", "PREOP_NODES", "INTRAOP_LANDMARKS", "PREOP_LANDMARKS",
           "TROCAR_TO_RAS", "MISSING_HOT_SPOTS", "STATUS", "RAS_FROM_LPS", "NO_POINTS_NAME", "POINT_COLOURS", "probe_pose", "point_list",
           "preop_points", "ras_from_trocar", "trocar_to_ras", "status", "StreamHealth"]

DEFAULT_PORT = 18944                 # OpenIGTLink's registered port, SlicerOpenIGTLink's default
PROBE_POSE = "ProbeTipToTrocar"
INTRAOP_NODES = "IntraopNodes"
PREOP_NODES = "PreopNodes"
INTRAOP_LANDMARKS = "IntraopLandmarks"
PREOP_LANDMARKS = "PreopLandmarks"
TROCAR_TO_RAS = "TrocarToRas"
MISSING_HOT_SPOTS = "MissingHotSpots"   # the hot spots not found yet, where the registration maps them (trocar frame)
STATUS = "Status"

RAS_FROM_LPS = np.diag([-1.0, -1.0, 1.0, 1.0])      # docs/design.md, Conventions: x and y negated (its own inverse)
INTRAOP_RGBA = (40, 200, 80, 255)                   # green: stored in surgery
PREOP_RGBA = (230, 120, 30, 255)                    # orange: seen on the SPECT
POINT_COLOURS = {INTRAOP_NODES: INTRAOP_RGBA, PREOP_NODES: PREOP_RGBA,
                 INTRAOP_LANDMARKS: (40, 150, 230, 255),   # blue: a landmark touched in surgery
                 PREOP_LANDMARKS: (170, 60, 200, 255),     # purple: a landmark placed on the CT
                 MISSING_HOT_SPOTS: (80, 200, 255, 255)}   # light blue, as on the feeds: a hot spot not found yet
NO_POINTS_NAME = "(none)"                           # the hidden point that stands for an empty list


def probe_pose(trocar_from_probe: np.ndarray, timestamp_s: float) -> bytes:
    """``ProbeTipToTrocar``: the (4, 4) probe pose in the trocar frame, mm; ``timestamp_s`` in Unix seconds."""
    return pyigtl.TransformMessage(np.asarray(trocar_from_probe, dtype=float), timestamp=timestamp_s,
                                   device_name=PROBE_POSE).pack()


def point_list(device: str, ids, xyz, rgba=None) -> bytes:
    """A POINT message named ``device``: one point per id at ``xyz`` (N, 3) mm, in ``rgba`` (the device's colour of
    :data:`POINT_COLOURS` by default).

    N = 0 (the last node undone, the preop nodes cleared) is sent as one hidden point (alpha 0) named
    ``NO_POINTS_NAME`` at the origin, not as a message without points: Slicer's OpenIGTLink library unpacks no
    body of size 0 and its POINT converter then drops the message, so Slicer would keep showing the old points.
    Slicer hides a point whose alpha is 0; clients that list the points should skip those.
    """
    positions = np.asarray(xyz, dtype=float).reshape(-1, 3)
    names = [str(i) for i in ids]
    rgba = rgba or POINT_COLOURS.get(device, INTRAOP_RGBA)
    if len(names) != len(positions):
        raise ValueError(f"{device}: {len(names)} names for {len(positions)} points")
    colours = [list(rgba)] * len(names)
    if not names:
        positions, names, colours = np.zeros((1, 3)), [NO_POINTS_NAME], [[*rgba[:3], 0]]
    return pyigtl.PointMessage(positions=positions, names=names, rgba_colors=colours, device_name=device).pack()


def preop_points(ids, xyz_lps, device: str = PREOP_NODES) -> bytes:
    """``PreopNodes`` (or ``PreopLandmarks``): points given in patient LPS (N, 3) mm, sent in RAS."""
    lps = np.asarray(xyz_lps, dtype=float).reshape(-1, 3)
    return point_list(device, ids, lps * RAS_FROM_LPS.diagonal()[:3])


def ras_from_trocar(intraop_from_preop: np.ndarray) -> np.ndarray:
    """(4, 4) trocar to RAS from a registration's ``intraop_from_preop`` (preop in LPS): ``ras_from_lps @ inverse``."""
    return RAS_FROM_LPS @ invert(np.asarray(intraop_from_preop, dtype=float))


def trocar_to_ras(intraop_from_preop: np.ndarray) -> bytes:
    """``TrocarToRas``: :func:`ras_from_trocar` of the current registration."""
    return pyigtl.TransformMessage(ras_from_trocar(intraop_from_preop), device_name=TROCAR_TO_RAS).pack()


def status(text: str) -> bytes:
    """``Status``: one line in words, ASCII (pyigtl's own fallback to UTF-8 catches the wrong exception and fails)."""
    return pyigtl.StringMessage(str(text).encode("ascii", "replace").decode("ascii"), device_name=STATUS).pack()


class StreamHealth:
    """The stream-health words of ``Status``: frame rate and how often the probe was found since the last time (the
    link's server thread keeps one)."""

    def __init__(self):
        self.last_text = ""
        self._t, self._frames, self._fixes = time.monotonic(), 0, 0

    def describe(self, now: float, frames: int, fixes: int, last_frame: float | None) -> str:
        span, new_frames, new_fixes = now - self._t, frames - self._frames, fixes - self._fixes
        if span < 0.5 and self.last_text:                   # too soon for a rate: keep the words as they were
            return self.last_text.split(";")[0]
        self._t, self._frames, self._fixes = now, frames, fixes
        if last_frame is None:
            return "waiting for frames"
        if new_frames == 0:
            return f"no frames for {now - last_frame:.0f} s"
        return f"video {new_frames / span:.1f} fps, probe found in {100.0 * new_fixes / new_frames:.0f}% of frames"
