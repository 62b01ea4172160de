"""Re-tracking a recorded session: every stored node's store window tracked again on the recorded video.

Why: a calibration found wrong after surgery, a better tracker or another probe model must not lose a session's
nodes. Each node's window is the ``n_frames`` frames of its last valid fixes before it was stored (its probe rows,
which carry their frame's grab time, up to the node's time); those frames are decoded from the video (frame k of the
files is row k of ``streams/frames``), tracked with the calibration, probe model and method given, and mapped through
the session's chain at the node's own mean IMU orientation (as the live store did). The node's new position is the
median of the new fixes; :func:`store_retracked` keeps it as a new version of the node (the old values stay on record
in the session's events, as any re-expression).

>>> result = retrack("s.h5", calibration=load_calibration("corrected.yaml"))
>>> [(node.id, node.moved_mm) for node in result.nodes]
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from snreg.camera import StereoCalibration
from snreg.chain import camera_to_trocar
from snreg.probe import ProbeModel
from snreg.session import IntraopNode, Session, SessionError, calibration_version
from snreg.session.reader import readable_rows
from snreg.session.schema import stereo_to_dict
from snreg.session.video import RecordedPairs
from snreg.tracking import StereoTracker, TrackingError, summarise

__all__ = ["RetrackedNode", "RetrackResult", "retrack", "store_retracked", "window_rows"]


@dataclass(frozen=True, eq=False)
class RetrackedNode:
    """One node before and after (mm, trocar and left-camera frames), the frames of its window and the fixes found."""

    node: IntraopNode
    after_trocar: np.ndarray | None
    after_camera: np.ndarray | None
    frames: int
    fixes: int
    problem: str = ""

    @property
    def moved_mm(self) -> float:
        return float("nan") if self.after_trocar is None else float(np.linalg.norm(self.after_trocar -
                                                                                   self.node.xyz_trocar))

    def to_json(self) -> dict:
        def xyz(value):
            return None if value is None else [round(float(v), 4) for v in value]
        return {"id": self.node.id, "label": self.node.label, "before_mm": xyz(self.node.xyz_trocar),
                "after_mm": xyz(self.after_trocar), "moved_mm": None if self.after_trocar is None else
                round(self.moved_mm, 4), "before_camera_mm": xyz(self.node.xyz_camera),
                "after_camera_mm": xyz(self.after_camera), "frames": self.frames, "fixes": self.fixes,
                "problem": self.problem}


@dataclass(frozen=True, eq=False)
class RetrackResult:
    nodes: list[RetrackedNode]
    stereo_version: str
    method: str


def window_rows(frame_times_ns: np.ndarray, probe_times_ns: np.ndarray, node: IntraopNode) -> np.ndarray:
    """The ``streams/frames`` rows of a node's store window: the frames of its last ``n_frames`` probe fixes up to its
    time (sorted row indices; fixes whose frame row is not recorded are left out)."""
    fixes = np.sort(probe_times_ns[probe_times_ns <= node.time_ns])[-max(int(node.n_frames), 1):]
    rows = np.searchsorted(frame_times_ns, fixes)
    inside = rows < len(frame_times_ns)
    rows, fixes = rows[inside], fixes[inside]
    return np.unique(rows[frame_times_ns[rows] == fixes])


def _times(stream) -> np.ndarray:
    rows = readable_rows(stream) if hasattr(stream, "id") else np.asarray(stream)
    return np.asarray(rows["t_host_ns"], dtype=np.int64)


def retrack(path: str | Path, *, calibration: StereoCalibration | None = None, probe: ProbeModel | None = None,
            method: str = "triangulation") -> RetrackResult:
    """Track every stored node's window again (the session's own calibration unless ``calibration``); SessionError
    in one sentence when the session has no video, no chain or a calibration of another image size."""
    with Session.open(path) as session:
        stored = session.calibration()
        segments = session.videos()
        nodes = session.intraop_records()
        frame_times, probe_times = (_times(session.stream(name)) for name in ("frames", "probe"))
    if not segments:
        raise SessionError(f"{path}: the session has no recorded video; only sessions recorded with video can be "
                           "re-tracked")
    if "chain" not in stored:
        raise SessionError(f"{path}: the session holds no chain calibration to map the re-tracked tips with")
    calibration = calibration or stored.get("stereo")
    if calibration is None:
        raise SessionError(f"{path}: the session holds no stereo calibration; give one with --calib")
    size = (segments[0].width, segments[0].height)
    if tuple(calibration.image_size) != size:
        raise SessionError(f"the calibration is for {calibration.image_size[0]}x{calibration.image_size[1]} images "
                           f"but the session's video is {size[0]}x{size[1]}; use a calibration made at that size")
    tracker = StereoTracker(calibration, probe, method=method)
    readers = RecordedPairs(path, segments)
    try:
        out = [_retrack_node(node, window_rows(frame_times, probe_times, node), readers, tracker, stored["chain"])
               for node in nodes]
    finally:
        readers.close()
    return RetrackResult(out, calibration_version(stereo_to_dict(calibration)), method)


def store_retracked(path: str | Path, result: RetrackResult, reason: str) -> int:
    """Keep the re-tracked positions as new versions of their nodes (the old ones stay on record); returns how many."""
    changed = [replace(r.node, xyz_trocar=r.after_trocar, xyz_camera=r.after_camera,
                       stereo_version=result.stereo_version) for r in result.nodes if r.after_trocar is not None]
    if changed:
        with Session.resume(path) as session:
            session.reexpress_nodes(changed, reason)
    return len(changed)


def _retrack_node(node: IntraopNode, rows: np.ndarray, readers: RecordedPairs, tracker: StereoTracker,
                  chain) -> RetrackedNode:
    if not np.all(np.isfinite(node.earth_from_imu)):
        return RetrackedNode(node, None, None, 0, 0, "the node has no IMU orientation on record (format 1)")
    tips, read = [], 0
    for row in rows:
        try:
            pair = readers.pair(int(row))
        except OSError:
            pair = None
        if pair is None:
            continue
        read += 1
        try:
            tips.append(tracker.track(*pair).tip)
        except TrackingError:
            continue
    if not tips:
        problem = "none of its window's frames is in the video" if not read else "no fix in its window's frames"
        return RetrackedNode(node, None, None, read, 0, problem)
    tips = np.array(tips)
    camera = summarise(tips).xyz
    trocar = summarise(camera_to_trocar(chain, node.earth_from_imu, tips)).xyz
    return RetrackedNode(node, trocar, camera, read, len(tips))
