"""A calibration change in a session with stored nodes: say so plainly, and re-express the nodes if asked.

Why: a node's trocar position is its camera-frame tip mapped through the stereo calibration and the chain of the
moment. After the trocar wizard (a new chain) or the stereo wizard (new cameras), new nodes land in another frame
than the stored ones (issue 12: the demo's tip jumped 372 mm), and a registration over both would mix two frames.
Each node keeps what it was measured with (camera tip, mean IMU orientation, calibration versions), so it can be
mapped again exactly: under a new chain, ``xyz_trocar = camera_to_trocar(chain, earth_from_imu, xyz_camera)``;
under a new stereo calibration, the camera tip is first re-triangulated from the pixels where the previous
calibration saw it (:func:`retriangulate`). The session does it all or nothing and keeps the old values on record
(:meth:`~snreg.session.Session.reexpress_nodes`).

A node stored while the camera's insertion was tracked (issue 27) was mapped at ``trocar_camera_mm``: the trocar
calibration's distance, the tracker's start, plus the slide tracked since. A new trocar calibration says where the
camera was at that start; the slide stays as tracked, so the node is mapped again at
``d_new = new_start + (d_node - old_start)`` (the same ``d_node`` when only the stereo calibration changed). The
old start is the distance of the chain the node was measured under: ``previous_chain`` (the chain just replaced),
or the session's stored chain when it is that one; a tracked node whose chain is neither cannot be re-expressed.
A node stored without tracking (NaN) is mapped at the new chain's own distance, as before.

A node's covariance (``cov_trocar_mm2``) goes along: its error was measured in the camera frame (and turned about the
pivot), so under a new chain it turns with the node's own change of frame, ``A C A^T`` with ``A`` the new
``trocar_from_camera`` rotation at the node's orientation times the old one's inverse; it becomes unknown (NaN) when
the chain it was measured under is no longer known. A new stereo calibration re-triangulates the tip; the change of
the stereo shape that brings is second order and left out (``snreg session retrack`` computes the covariance anew).

>>> change = calibration_change(session, stereo, chain, previous_stereo=old_stereo)
>>> if change is not None:                # ask: change.message, change.question
...     reexpress(session, stereo, chain, previous_stereo=old_stereo)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from snreg.camera import StereoCalibration
from snreg.chain import ChainCalibration, camera_to_trocar, trocar_from_camera
from snreg.session import IntraopNode, Session, calibration_version
from snreg.session.schema import stereo_to_dict

__all__ = ["CalibrationChange", "calibration_change", "reexpress", "retriangulate", "mixed_calibration_note",
           "id_list"]


@dataclass(frozen=True, eq=False)
class CalibrationChange:
    """Stored nodes mapped with another calibration than ``stereo_version``/``chain_version`` (the current one):
    ``movable`` can be re-expressed exactly, ``stuck`` cannot (no IMU orientation on record: files of format 1; or
    measured with a stereo calibration other than the one just replaced; or with a tracked insertion under a chain
    no longer known). ``starts``: for each movable node with a tracked insertion, the distance (mm) of the chain it
    was measured under (its tracking's start)."""

    movable: list[IntraopNode]
    stuck: list[IntraopNode]
    stereo_changed: bool
    chain_changed: bool
    stereo_version: str
    chain_version: str
    starts: dict[str, float] = field(default_factory=dict)

    @property
    def message(self) -> str:
        """What changed and what it means for the stored nodes, in words."""
        what = " and ".join(w for w, changed in (("stereo calibration", self.stereo_changed),
                                                 ("trocar calibration (chain)", self.chain_changed)) if changed)
        nodes = self.movable + self.stuck
        text = (f"The {what} changed. {id_list(nodes)} {'was' if len(nodes) == 1 else 'were'} stored under the "
                f"previous one, so new nodes will not be in the same frame as {'it' if len(nodes) == 1 else 'them'}"
                " and a registration would mix the two.")
        if self.stuck:
            text += (f" {id_list(self.stuck)} cannot be re-expressed (measured before orientations were kept, or with "
                     "an older calibration): store them again or undo them.")
        return text

    @property
    def question(self) -> str:
        """The offer to make ("" when no node can be re-expressed)."""
        if not self.movable:
            return ""
        tracked = [node for node in self.movable if node.id in self.starts]
        slid = (f" {id_list(tracked)} {'was' if len(tracked) == 1 else 'were'} stored with the camera's insertion "
                "tracked: the slide tracked since the start is kept and added to the new trocar-camera distance."
                if tracked and self.chain_changed else "")
        return (f"Re-express {id_list(self.movable)} under the new calibration?{slid} Their positions as first stored "
                "stay on record in the session.")


def calibration_change(session: Session, stereo: StereoCalibration, chain: ChainCalibration, *,
                       previous_stereo: StereoCalibration | None = None,
                       previous_chain: ChainCalibration | None = None) -> CalibrationChange | None:
    """The stored nodes not mapped with ``stereo`` and ``chain``; None when there are none. ``previous_stereo`` and
    ``previous_chain``: the calibrations just replaced (module docstring)."""
    stereo_version, chain_version = calibration_version(stereo_to_dict(stereo)), calibration_version(chain.to_dict())
    previous = calibration_version(stereo_to_dict(previous_stereo)) if previous_stereo is not None else None
    distances = {version: known.trocar_camera_mm for version, known in _chains(session, chain, previous_chain).items()}
    movable, stuck, starts = [], [], {}
    for node in session.intraop_records(kind=None):
        if node.measured_under == (stereo_version, chain_version):
            continue
        tracked = np.isfinite(node.trocar_camera_mm)
        known = (np.isfinite(node.earth_from_imu).all() and node.stereo_version in (stereo_version, previous)
                 and (not tracked or node.chain_version in distances))
        (movable if known else stuck).append(node)
        if known and tracked:
            starts[node.id] = distances[node.chain_version]
    if not movable and not stuck:
        return None
    nodes = movable + stuck
    return CalibrationChange(movable, stuck, any(n.stereo_version != stereo_version for n in nodes),
                             any(n.chain_version != chain_version for n in nodes), stereo_version, chain_version,
                             starts)


def _chains(session: Session, chain: ChainCalibration, previous_chain: ChainCalibration | None) -> dict:
    """{chain version: chain} of the chains a node may have been measured under: the new one, the one just replaced,
    the session's stored one."""
    stored = session.calibration().get("chain")
    return {calibration_version(c.to_dict()): c for c in (stored, previous_chain, chain) if c is not None}


def reexpress(session: Session, stereo: StereoCalibration, chain: ChainCalibration, *,
              previous_stereo: StereoCalibration | None = None,
              previous_chain: ChainCalibration | None = None) -> list[IntraopNode]:
    """Map every movable node of :func:`calibration_change` through ``stereo`` and ``chain`` (a node with a tracked
    insertion at its slide from the new start: module docstring), in one durable step (all or none); returns the
    nodes as now stored (empty when there was nothing to do)."""
    change = calibration_change(session, stereo, chain, previous_stereo=previous_stereo, previous_chain=previous_chain)
    if change is None or not change.movable:
        return []
    chains = _chains(session, chain, previous_chain)
    updated = []
    for node in change.movable:
        camera = np.asarray(node.xyz_camera, dtype=float)
        if node.stereo_version != change.stereo_version:
            camera = retriangulate(camera, previous_stereo, stereo)
        insertion, mapping = float("nan"), chain
        if node.id in change.starts:
            insertion = chain.trocar_camera_mm + (node.trocar_camera_mm - change.starts[node.id])
            mapping = chain.with_insertion(insertion)
        updated.append(dataclasses.replace(node, xyz_camera=camera,
                                           xyz_trocar=camera_to_trocar(mapping, node.earth_from_imu, camera),
                                           stereo_version=change.stereo_version, chain_version=change.chain_version,
                                           trocar_camera_mm=insertion,
                                           cov_trocar_mm2=_carried(node, chains.get(node.chain_version), mapping)))
    session.reexpress_nodes(updated, reason=change.message)
    stored = {node.id: node for node in session.intraop_records(kind=None)}
    return [stored[node.id] for node in updated]


def _carried(node: IntraopNode, old: ChainCalibration | None, new: ChainCalibration) -> np.ndarray:
    """The node's covariance (3, 3) mm^2 in the frame of ``new``: turned by the change of its trocar frame at its own
    orientation; NaN when the chain it was measured under (``old``) is not known."""
    if old is None:
        return np.full((3, 3), np.nan)
    turn = trocar_from_camera(new, node.earth_from_imu)[:3, :3] @ trocar_from_camera(old, node.earth_from_imu)[:3, :3].T
    return turn @ np.asarray(node.cov_trocar_mm2, dtype=float) @ turn.T


def retriangulate(point_camera, old: StereoCalibration, new: StereoCalibration) -> np.ndarray:
    """(3,) mm: the left-camera point that ``new`` triangulates from the pixels where ``old`` saw ``point_camera``
    (3,) mm (projected through old's intrinsics, distortion and R, T; undistorted and rectified by new's)."""
    point = np.asarray(point_camera, dtype=float).reshape(1, 1, 3)
    right_rvec = cv2.Rodrigues(np.asarray(old.R, dtype=float))[0]
    left_px = cv2.projectPoints(point, np.zeros(3), np.zeros(3), old.K1, old.D1)[0]
    right_px = cv2.projectPoints(point, right_rvec, np.asarray(old.T, dtype=float).reshape(3), old.K2, old.D2)[0]
    rect_left = cv2.undistortPoints(left_px, new.K1, new.D1, R=new.R1, P=new.P1).reshape(2, 1)
    rect_right = cv2.undistortPoints(right_px, new.K2, new.D2, R=new.R2, P=new.P2).reshape(2, 1)
    homog = cv2.triangulatePoints(new.P1, new.P2, rect_left, rect_right).reshape(4)
    return np.asarray(new.R1, dtype=float).T @ (homog[:3] / homog[3])


def mixed_calibration_note(nodes: Sequence[IntraopNode]) -> str:
    """One sentence when ``nodes`` were mapped with more than one calibration (which nodes under which), else ""."""
    groups: dict[tuple[str, str], list[IntraopNode]] = {}
    for node in nodes:
        groups.setdefault(node.measured_under, []).append(node)
    if len(groups) < 2:
        return ""
    parts = [f"{id_list(members)} under {_version_text(key)}" for key, members in groups.items()]
    return (f"These nodes were mapped with {len(groups)} different calibrations ({'; '.join(parts)}): a registration "
            "mixes two frames; re-express the older nodes (Acquisition) or undo them first.")


def id_list(nodes: Sequence[IntraopNode]) -> str:
    """"SN1", "SN1 and SN2", "SN1, SN2 and SN3" ... (at most six named)."""
    ids = [node.id for node in nodes]
    if len(ids) > 6:
        return f"{', '.join(ids[:5])} and {len(ids) - 5} more"
    return ids[0] if len(ids) == 1 else f"{', '.join(ids[:-1])} and {ids[-1]}"


def _version_text(key: tuple[str, str]) -> str:
    stereo, chain = key
    if not stereo and not chain:
        return "an unrecorded calibration"
    return f"stereo {stereo or '?'}, chain {chain or '?'}"
