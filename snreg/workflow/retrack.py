"""Re-tracking a recorded session: the camera's insertion over the recorded video, and every stored node's store
window tracked again and mapped with it.

Why: a calibration found wrong after surgery, a better tracker or another probe model must not lose a session's
nodes, nor must a camera that slid while its insertion was not tracked (issue 27). ``insertion``: "video" tracks the
camera's insertion over the recorded video, "chain" takes the chain's constant distance (the thesis' still camera),
"auto" (default) the video when the session tracked the insertion live (its ``streams/camera`` has rows), else the
chain: the insertion tracker reads tissue that moves as a whole (breathing, a retractor, the old demo's tissue plane
that followed the probe) as a slide, so it is not imposed on a session recorded without it unless asked.

With the insertion followed, the video is read once, pair by pair from the recording's first (frame k of the files is
row k of ``streams/frames``): the probe is tracked in each pair (and left out of the tissue) and the insertion is
tracked (:mod:`snreg.odometry`) with the session's IMU
orientation at the pair's grab time (the stored samples fused again, :func:`~snreg.session.pose_streams.orientations_at`),
from the session chain's distance at the first pair with tissue in view; a lost pair keeps the last tracked
insertion, as the live acquisition did. Each node's window is the ``n_frames`` frames of its last valid fixes before
it was stored (its probe rows, which carry their frame's grab time, up to the node's time); their tips, tracked with
the calibration, probe model and method given, are mapped through the session's chain at each pair's insertion and
the node's own mean IMU orientation (as the live store did). The node's new position is the median of the new
fixes, its insertion the median over them (NaN while no pair up to it was tracked: the chain's own distance maps it
then), its covariance computed anew from the new fixes (:func:`~snreg.tracking.uncertainty.node_covariance` with its
default magnitudes, the insertion's sd as tracked); :func:`store_retracked` keeps them as a new version of the node
(the old values stay on record in the session's events, as any re-expression). The session's ``streams/camera``
keeps what was tracked live. Stored landmarks are re-tracked as nodes are (their ``kind`` in the output).

>>> result = retrack("s.h5", calibration=load_calibration("corrected.yaml"))
>>> [(node.id, node.moved_mm) for node in result.nodes]
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from snreg.camera import StereoCalibration
from snreg.chain import ChainCalibration, camera_to_trocar
from snreg.geometry import rotation_angle_deg
from snreg.odometry import InsertionTracker
from snreg.odometry.held import held_sd_mm
from snreg.probe import ProbeModel
from snreg.session import IntraopNode, Session, SessionError, calibration_version
from snreg.session.pose_streams import orientations_at
from snreg.session.reader import readable_rows
from snreg.session.schema import stereo_to_dict
from snreg.session.video import RecordedPairs, rows_with_video
from snreg.tracking import ProbeFix, StereoTracker, TrackingError, summarise
from snreg.tracking.uncertainty import NodeUncertainty, node_covariance

__all__ = ["RetrackedNode", "RetrackResult", "VideoInsertion", "retrack", "store_retracked", "window_rows",
           "INSERTION_SOURCES", "insertion_tracked_live"]

INSERTION_SOURCES = ("auto", "video", "chain")


@dataclass(frozen=True, eq=False)
class RetrackedNode:
    """One node before and after (mm, trocar and left-camera frames; the insertion it is mapped with, NaN when
    untracked; the covariance after, mm^2, trocar frame), the frames of its window, the fixes found and how many of
    them had the insertion lost (held)."""

    node: IntraopNode
    after_trocar: np.ndarray | None
    after_camera: np.ndarray | None
    frames: int
    fixes: int
    problem: str = ""
    after_insertion_mm: float = float("nan")
    insertion_lost: int = 0
    after_cov: np.ndarray | None = None

    @property
    def moved_mm(self) -> float:
        return float("nan") if self.after_trocar is None else float(np.linalg.norm(self.after_trocar -
                                                                                   self.node.xyz_trocar))

    def to_json(self) -> dict:
        def xyz(value):
            return None if value is None else [round(float(v), 4) for v in value]
        def mm(value):
            return round(float(value), 4) if np.isfinite(value) else None
        return {"id": self.node.id, "kind": self.node.kind, "label": self.node.label,
                "before_mm": xyz(self.node.xyz_trocar),
                "after_mm": xyz(self.after_trocar), "moved_mm": None if self.after_trocar is None else
                round(self.moved_mm, 4), "before_camera_mm": xyz(self.node.xyz_camera),
                "after_camera_mm": xyz(self.after_camera), "before_trocar_camera_mm": mm(self.node.trocar_camera_mm),
                "after_trocar_camera_mm": mm(self.after_insertion_mm), "insertion_lost": self.insertion_lost,
                "after_cov_trocar_mm2": None if self.after_cov is None else np.round(self.after_cov, 4).tolist(),
                "frames": self.frames, "fixes": self.fixes, "problem": self.problem}


@dataclass(frozen=True, eq=False)
class VideoInsertion:
    """The insertion over the recorded video: per ``streams/frames`` row the insertion it is mapped with (``used_mm``,
    the start before any pair was tracked) and the sd of its change since the start (the tracker's; a held one's
    grown with the time lost and the IMU's turn since, :mod:`snreg.odometry.held`), whether that row's
    own pair was tracked, and whether any pair up to it was (``known``); how the orientations were got, in words."""

    used_mm: np.ndarray
    tracked: np.ndarray
    known: np.ndarray
    pairs: int
    orientation: str
    sd_mm: np.ndarray

    def to_json(self) -> dict:
        tracked = int(self.tracked.sum())
        return {"pairs": self.pairs, "tracked": tracked, "lost": self.pairs - tracked, "orientation": self.orientation}


@dataclass(frozen=True, eq=False)
class RetrackResult:
    nodes: list[RetrackedNode]
    stereo_version: str
    method: str
    insertion: VideoInsertion | None = None


def insertion_tracked_live(session: Session) -> bool:
    """Whether ``session`` tracked the camera's insertion live (its ``streams/camera`` has rows): the rule by which
    re-tracking's "auto" follows the insertion over the video and a replay (:mod:`snreg.demo.replay`) tracks it, so
    neither imposes the insertion tracker on a session recorded without it (module docstring)."""
    return len(session.stream("camera")) > 0


def window_rows(frame_times_ns: np.ndarray, probe_times_ns: np.ndarray, node: IntraopNode) -> np.ndarray:
    """The ``streams/frames`` rows of a node's store window: the frames of its last ``n_frames`` probe fixes up to its
    time (sorted row indices; fixes whose frame row is not recorded are left out)."""
    fixes = np.sort(probe_times_ns[probe_times_ns <= node.time_ns])[-max(int(node.n_frames), 1):]
    rows = np.searchsorted(frame_times_ns, fixes)
    inside = rows < len(frame_times_ns)
    rows, fixes = rows[inside], fixes[inside]
    return np.unique(rows[frame_times_ns[rows] == fixes])


def retrack(path: str | Path, *, calibration: StereoCalibration | None = None, probe: ProbeModel | None = None,
            method: str = "triangulation", insertion: str = "auto") -> RetrackResult:
    """Track every stored node's window again (the session's own calibration unless ``calibration``) and map it with
    the insertion from ``insertion`` (module docstring); SessionError in one sentence when the session has no video,
    no chain or a calibration of another image size."""
    if insertion not in INSERTION_SOURCES:
        raise ValueError(f"the insertion comes from {', '.join(INSERTION_SOURCES)}, not {insertion!r}")
    with Session.open(path) as session:
        stored = session.calibration()
        segments = session.videos()
        nodes = session.intraop_records(kind=None)
        frames, probe_rows, imu = (_rows(session.stream(name)) for name in ("frames", "probe", "imu"))
        tracked_live = insertion_tracked_live(session)
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
    frame_times = np.asarray(frames["t_host_ns"], dtype=np.int64)
    probe_times = np.asarray(probe_rows["t_host_ns"], dtype=np.int64)
    windows = {node.id: window_rows(frame_times, probe_times, node) for node in nodes}
    wanted = set(np.concatenate([np.zeros(0, int), *windows.values()]).tolist())
    readers = RecordedPairs(path, segments)
    try:
        tracker = StereoTracker(calibration, probe, method=method)
        if insertion == "video" or (insertion == "auto" and tracked_live):
            followed, fixes, read = _follow(readers, path, segments, frame_times, imu, calibration, stored["chain"],
                                           probe, tracker, wanted)
        else:
            followed, (fixes, read) = None, _window_fixes(readers, sorted(wanted), tracker)
    finally:
        readers.close()
    out = [_retrack_node(node, windows[node.id], fixes, read, followed, stored["chain"], tracker) for node in nodes]
    return RetrackResult(out, calibration_version(stereo_to_dict(calibration)), method, followed)


def store_retracked(path: str | Path, result: RetrackResult, reason: str) -> int:
    """Keep the re-tracked positions as new versions of their nodes (the old ones stay on record); returns how many."""
    changed = [replace(r.node, xyz_trocar=r.after_trocar, xyz_camera=r.after_camera,
                       stereo_version=result.stereo_version, trocar_camera_mm=r.after_insertion_mm,
                       cov_trocar_mm2=r.after_cov)
               for r in result.nodes if r.after_trocar is not None]
    if changed:
        with Session.resume(path) as session:
            session.reexpress_nodes(changed, reason)
    return len(changed)


def _window_fixes(readers: RecordedPairs, rows, tracker: StereoTracker) -> tuple[dict[int, ProbeFix], set[int]]:
    """The probe fix tracked in each of ``rows`` by row, and the rows whose pair was read."""
    fixes, read = {}, set()
    for row in rows:
        pair = _pair(readers, row)
        if pair is None:
            continue
        read.add(int(row))
        fix = _track(tracker, pair)
        if fix is not None:
            fixes[int(row)] = fix
    return fixes, read


def _follow(readers: RecordedPairs, path, segments, frame_times: np.ndarray, imu: np.ndarray,
            calibration: StereoCalibration, chain: ChainCalibration, probe: ProbeModel | None,
            tracker: StereoTracker, wanted: set[int]) -> tuple[VideoInsertion, dict[int, ProbeFix], set[int]]:
    """Every recorded pair once, in order: the probe tracked (left out of the tissue; ``tracker``'s tip kept in the
    ``wanted`` rows) and the insertion tracked. Returns the insertion, the probe fixes by row and the wanted rows
    that were read."""
    n_rows = len(frame_times)
    recorded = np.flatnonzero(rows_with_video(path, segments, n_rows))
    orientations, source = orientations_at(imu, frame_times[recorded])
    masker = tracker if tracker.method == "triangulation" else StereoTracker(calibration, probe)
    follower = InsertionTracker(calibration, chain, probe=probe)
    used, sd = np.full(n_rows, follower.start_mm), np.full(n_rows, NodeUncertainty.insertion_sd_mm)
    tracked, known = np.zeros(n_rows, bool), np.zeros(n_rows, bool)
    fixes, read, last, seen = {}, set(), follower.start_mm, False
    known_ns, known_orientation, known_sd = 0, np.eye(3), 0.0     # the last tracked pair's time, IMU and change sd
    for k, row in enumerate(recorded):
        pair = _pair(readers, row)
        if pair is None:
            continue
        fix = _track(masker, pair)
        if row in wanted:
            read.add(int(row))
            own = fix if tracker is masker else _track(tracker, pair)
            if own is not None:
                fixes[int(row)] = own
        estimate = follower.update(*pair, orientations[k], probe_fix=fix)
        if estimate.tracked:
            last, seen, tracked[row], sd[row] = estimate.trocar_camera_mm, True, True, estimate.change_sd_mm
            known_ns, known_orientation, known_sd = int(frame_times[row]), orientations[k], estimate.change_sd_mm
        elif seen:
            sd[row] = held_sd_mm(known_sd, (int(frame_times[row]) - known_ns) / 1e9,
                                 float(rotation_angle_deg(np.asarray(known_orientation).T @ orientations[k])))
        used[row], known[row] = last, seen
    return VideoInsertion(used, tracked, known, len(recorded), source, sd), fixes, read


def _pair(readers: RecordedPairs, row):
    try:
        return readers.pair(int(row))
    except OSError:
        return None


def _track(tracker: StereoTracker, pair):
    try:
        return tracker.track(*pair)
    except TrackingError:
        return None


def _rows(stream) -> np.ndarray:
    return readable_rows(stream) if hasattr(stream, "id") else np.asarray(stream)


def _retrack_node(node: IntraopNode, rows: np.ndarray, fixes: dict[int, ProbeFix], read: set[int],
                  insertion: VideoInsertion | None, chain: ChainCalibration, tracker: StereoTracker) -> RetrackedNode:
    frames = sum(int(row) in read for row in rows)
    if not np.all(np.isfinite(node.earth_from_imu)):
        return RetrackedNode(node, None, None, 0, 0, "the node has no IMU orientation on record (format 1)")
    found = [int(row) for row in rows if int(row) in fixes]
    if not found:
        problem = "none of its window's frames is in the video" if not frames else "no fix in its window's frames"
        return RetrackedNode(node, None, None, frames, 0, problem)
    camera_tips = np.array([fixes[row].tip for row in found])
    camera = summarise(camera_tips).xyz
    known = insertion is not None and insertion.known[found].all()
    used = insertion.used_mm[found] if known else np.full(len(found), np.nan)
    chains = {d: chain.with_insertion(d) for d in np.unique(used)} if known else {}
    trocar = np.array([camera_to_trocar(chains[d] if known else chain, node.earth_from_imu, tip)
                       for d, tip in zip(used, camera_tips)])
    mapped = chain.with_insertion(float(np.median(used))) if known else chain
    cov = node_covariance(NodeUncertainty(), tracker.calibration, tracker.probe, mapped, node.earth_from_imu, camera,
                          np.mean([fixes[row].axis for row in found], axis=0), window_camera=camera_tips,
                          insertion_sd_mm=float(np.median(insertion.sd_mm[found])) if known else None)
    lost = 0 if insertion is None else int(np.sum(~insertion.tracked[found]))
    return RetrackedNode(node, summarise(trocar).xyz, camera, frames, len(found), "",
                         float(np.median(used)) if known else float("nan"), lost, cov)
