"""A saved session made ready for offline review: everything copied out of the file, streams as plot-ready arrays.

Why: the review screen must show an hour of recording (750k IMU rows at 208 Hz) without blocking and
without holding the file open, so the reading and the fusing live here, Qt-free and testable: the GUI
runs :func:`load_review` and then :func:`fuse_imu_blocks` in workers and only plots what they return.

All times are seconds on the host clock (``time.perf_counter_ns``, docs/design.md, Conventions) from the review
origin ``t0_ns``: the first sample of any stream (the first node when there are no streams).

>>> review = load_review("s.h5")      # SessionError in one sentence when the file cannot be read
>>> review.nodes, review.landmarks    # the stored nodes and, apart, the stored anatomical landmarks (kind "landmark")
>>> euler = fuse_imu(review.imu)      # (N, 3) yaw, pitch, roll in degrees, as the live filter computed them
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import h5py
import numpy as np

from snreg.imu.fusion import Fusion
from snreg.imu.protocol import DEFAULT_ODR_HZ, DEVICE_CLOCK_WRAP_US
from snreg.landmarks import LANDMARK, NODE
from snreg.nodes import NodeSet
from snreg.preop.gravity import PreopDown
from snreg.registration.report import PairRow, pair_table
from snreg.session import Session, SessionError, StoredRegistration
from snreg.session.reader import readable_rows
from snreg.session.schema import CAMERA_STATES

__all__ = ["ImuSeries", "ProbeSeries", "FrameSeries", "CameraSeries", "ReviewNode", "ReviewRegistration", "SessionReview",
           "load_review", "fuse_imu_blocks", "fuse_imu", "frame_series", "gap_after", "imu_gap_after", "with_gaps",
           "lost_stretches", "clock_figures", "GAP_PERIODS"]

GAP_PERIODS = 3.0          # an interval longer than this many median frame periods is a gap (>= 2 frames lost)
FUSION_BLOCK = 65536       # samples fused between progress reports: ~5 min of IMU data, ~0.4 s of work at ~6 us/sample


@dataclass(frozen=True, eq=False)
class ImuSeries:
    """Raw IMU samples: host time (N,) s from the origin; device clock (N,) us; accel (N, 3) g; gyro (N, 3) deg/s."""

    t_s: np.ndarray
    t_device_us: np.ndarray
    accel_g: np.ndarray
    gyro_dps: np.ndarray


@dataclass(frozen=True, eq=False)
class ProbeSeries:
    """Probe fixes: time (N,) s, tip (N, 3) mm in the left camera frame, tracking quality (N,)."""

    t_s: np.ndarray
    tip_mm: np.ndarray
    quality: np.ndarray


@dataclass(frozen=True, eq=False)
class CameraSeries:
    """The camera's tracked insertion (``streams/camera``): time (N,) s, insertion (N,) mm (NaN where lost), whether
    each pair was tracked, quality (N,) 0-1 and the pivot model's residual (N,) mm. Empty when the insertion was not
    tracked (files of format 3 among them): the chain's constant distance mapped every node then."""

    t_s: np.ndarray
    trocar_camera_mm: np.ndarray
    tracked: np.ndarray
    quality: np.ndarray
    residual_mm: np.ndarray

    @classmethod
    def empty(cls) -> "CameraSeries":
        return cls(np.zeros(0), np.zeros(0), np.zeros(0, bool), np.zeros(0), np.zeros(0))


@dataclass(frozen=True, eq=False)
class FrameSeries:
    """Frame times (N,) s; the rate per whole second (``rate_edges_s`` (K + 1,), ``rate_hz`` (K,)), the median
    rate, and the gaps (G, 2): start and duration in s of every interval over :data:`GAP_PERIODS` periods."""

    t_s: np.ndarray
    rate_edges_s: np.ndarray
    rate_hz: np.ndarray
    median_rate_hz: float
    gaps_s: np.ndarray


@dataclass(frozen=True, eq=False)
class ReviewNode:
    """A stored node: positions mm (trocar, left camera), time s from the origin, snapshots RGB (H, W, 3) or None,
    the insertion it was mapped with (mm, NaN when untracked) and its own error's covariance (3, 3) mm^2, trocar frame
    (NaN when not stored). ``kind``: ``"node"``, or ``"landmark"`` for an anatomical landmark touched and stored with
    Store landmark (``id`` = its name), never a node."""

    id: str
    label: str
    t_s: float
    xyz_trocar: np.ndarray
    xyz_camera: np.ndarray
    spread_mm: float
    n_frames: int
    counts: float
    left_rgb: np.ndarray | None
    right_rgb: np.ndarray | None
    trocar_camera_mm: float = float("nan")
    cov_trocar_mm2: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    kind: str = NODE

    @property
    def is_landmark(self) -> bool:
        return self.kind == LANDMARK


@dataclass(frozen=True, eq=False)
class ReviewRegistration:
    """A stored registration and its pairing table (:func:`~snreg.registration.report.pair_table`), one row per
    intraop node it paired, named by the ids stored with it (a file written before ids were stored: the session's
    node lists when their lengths fit, else ``"#k"`` by index)."""

    n: int
    method: str
    rms_mm: float
    rows: list[PairRow]
    final: bool = False         # the one marked final in the session

    @property
    def n_paired(self) -> int:
        return sum(row.paired for row in self.rows)

    @property
    def intraop_ids(self) -> list[str]:
        return [row.intraop_id for row in self.rows]

    @property
    def preop_ids(self) -> list[str]:
        """The hot spot of each row (:data:`~snreg.registration.report.NO_HOT_SPOT` for a node from none)."""
        return [row.preop_id for row in self.rows]

    @property
    def distances_mm(self) -> np.ndarray:
        return np.array([row.distance_mm for row in self.rows])

    @property
    def confidence(self) -> np.ndarray:
        return np.array([row.confidence for row in self.rows])


@dataclass(frozen=True, eq=False)
class SessionReview:
    """What a session holds, in memory. ``stereo_rms_px``/``imu_trocar_mm``/``trocar_camera_mm`` are None when
    that calibration was not stored; ``damaged``: the HDF5 file was unreadable and the journal was read instead.
    ``nodes`` are the stored nodes alone (what is counted and paired), ``landmarks`` the stored anatomical landmarks;
    ``stored`` both, in the order stored; ``preop``, ``preop_landmarks`` and ``preop_down`` the preop set stored with
    the session (the SPECT's hot spots, the CT's landmarks, what gives their down)."""

    path: str
    case_id: str
    created_utc: str
    snreg_version: str
    format_version: int
    damaged: bool
    stereo_rms_px: float | None
    imu_trocar_mm: float | None
    trocar_camera_mm: float | None
    t0_ns: int
    imu: ImuSeries
    probe: ProbeSeries
    frames: FrameSeries
    nodes: list[ReviewNode]
    registrations: list[ReviewRegistration]
    problems: tuple[str, ...] = ()          # what could not be read, in words (Session.problems)
    camera: CameraSeries = field(default_factory=CameraSeries.empty)
    landmarks: list[ReviewNode] = field(default_factory=list)
    preop: NodeSet | None = None                 # the preop nodes stored with the session (None: none stored)
    preop_landmarks: NodeSet | None = None       # the preop (CT) landmarks stored with them (empty: none)
    preop_down: PreopDown | None = None          # their patient position and table tilt (None: not known)
    session: Session | None = None               # the session as read, closed: all but its streams in memory, for a
                                                 # registration panel to show it read-only

    @property
    def stored(self) -> list[ReviewNode]:
        """Nodes and landmarks in the order stored (by time; a node before a landmark of the same time)."""
        return sorted(self.nodes + self.landmarks, key=lambda point: point.t_s)


def load_review(path: str | Path) -> SessionReview:
    """Read a session once and close it; :class:`SessionError` in one sentence when it cannot be read."""
    try:
        with Session.open(path) as session:
            streams = {name: _rows(session.stream(name)) for name in ("imu", "probe", "frames", "camera")}
            records = session.intraop_records()
            landmarks = session.intraop_records(LANDMARK)
            preop = session.preop_nodes()
            registrations = session.registrations()
            calibration = session.calibration()
            header, damaged, problems = dict(session.header), session.damaged, tuple(session.problems)
            preop_down, preop_landmarks = session.preop_down(), session.preop_landmarks()
    except SessionError:
        raise
    except (OSError, ValueError, KeyError, RuntimeError) as err:
        raise SessionError(f"{path}: the session could not be read ({err}); check the file or run "
                           "'snreg session recover'") from None
    t0_ns = _origin(streams, [r.time_ns for r in records + landmarks])
    imu, probe, frames, camera = streams["imu"], streams["probe"], streams["frames"], streams["camera"]
    stereo, chain = calibration.get("stereo"), calibration.get("chain")
    node_ids = [r.id for r in records]
    return SessionReview(
        str(path), str(header.get("case_id", "")), str(header.get("created_utc", "")),
        str(header.get("snreg_version", "")), int(header.get("format_version", 0)), bool(damaged),
        None if stereo is None else float(stereo.rms_reprojection_px),
        None if chain is None else chain.imu_trocar_mm, None if chain is None else chain.trocar_camera_mm, t0_ns,
        ImuSeries(_seconds(imu["t_host_ns"], t0_ns), np.asarray(imu["t_device_ns"] // 1000, dtype=np.int64),
                  np.ascontiguousarray(imu["acc_g"], dtype=float), np.ascontiguousarray(imu["gyro_dps"], dtype=float)),
        ProbeSeries(_seconds(probe["t_host_ns"], t0_ns), np.ascontiguousarray(probe["tip_mm"], dtype=float),
                    np.ascontiguousarray(probe["quality"], dtype=float)),
        frame_series(_seconds(frames["t_host_ns"], t0_ns)),
        [_review_node(r, t0_ns) for r in records],
        [_registration(stored, node_ids, None if preop is None else preop.ids) for stored in registrations], problems,
        CameraSeries(_seconds(camera["t_host_ns"], t0_ns), np.asarray(camera["trocar_camera_mm"], dtype=float),
                     np.asarray(camera["state"]) == CAMERA_STATES.index("tracked"),
                     np.asarray(camera["quality"], dtype=float), np.asarray(camera["residual_mm"], dtype=float)),
        [_review_node(r, t0_ns) for r in landmarks], preop, preop_landmarks, preop_down, session)


def _review_node(r, t0_ns: int) -> ReviewNode:
    """A stored intraop point (node or landmark, by its ``kind``) as the review shows it."""
    return ReviewNode(r.id, r.label, (r.time_ns - t0_ns) / 1e9, np.asarray(r.xyz_trocar, dtype=float),
                      np.asarray(r.xyz_camera, dtype=float), r.spread_mm, r.n_frames, r.counts,
                      _decode_rgb(r.left_jpeg), _decode_rgb(r.right_jpeg), float(r.trocar_camera_mm),
                      np.asarray(r.cov_trocar_mm2, dtype=float), r.kind)


def frame_series(t_s: np.ndarray) -> FrameSeries:
    """Rate per whole second and gaps of frame times ``t_s`` (N,) in seconds."""
    t_s = np.sort(np.asarray(t_s, dtype=float))
    if len(t_s) < 2:
        return FrameSeries(t_s, np.zeros(1), np.zeros(0), float("nan"), np.zeros((0, 2)))
    edges = np.arange(np.floor(t_s[0]), np.floor(t_s[-1]) + 2.0)
    counts, _ = np.histogram(t_s, bins=edges)
    steps = np.diff(t_s)
    period = float(np.median(steps))
    gap = steps > GAP_PERIODS * period
    return FrameSeries(t_s, edges, counts.astype(float), 1.0 / period if period > 0 else float("inf"),
                       np.column_stack([t_s[:-1][gap], steps[gap]]))


def gap_after(t_s: np.ndarray, period_s: float | None = None) -> np.ndarray:
    """Indices k (G,) after which a stream ``t_s`` (N,) s has a gap: ``t[k+1] - t[k]`` over :data:`GAP_PERIODS`
    periods (``period_s``, or the stream's median step)."""
    t_s = np.asarray(t_s, dtype=float)
    if len(t_s) < 2:
        return np.zeros(0, dtype=int)
    steps = np.diff(t_s)
    period = float(np.median(steps)) if period_s is None or not np.isfinite(period_s) else float(period_s)
    return np.flatnonzero(steps > GAP_PERIODS * period)


def imu_gap_after(imu: ImuSeries) -> np.ndarray:
    """Indices k (G,) after which the IMU stream has a gap, judged on the board's own sample clock (micros(), modulo
    2**32, so its wrap is no gap): the host stamps samples as the serial reader gets them, in bursts (most host steps
    are 0), so a host-time median says nothing of a gap. A board restart (its clock back near 0) is a gap too."""
    if len(imu.t_device_us) < 2:
        return np.zeros(0, dtype=int)
    steps_s = (np.diff(np.asarray(imu.t_device_us, dtype=np.int64)) % DEVICE_CLOCK_WRAP_US) / 1e6
    ahead = steps_s[steps_s > 0]
    period = float(np.median(ahead)) if len(ahead) else None
    return gap_after(np.concatenate([[0.0], np.cumsum(steps_s)]), period)


def with_gaps(t_s: np.ndarray, values: np.ndarray, after: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``t_s`` (N,) and ``values`` (N, ...) with a NaN row after each index in ``after``: a curve drawn with
    ``connect="finite"`` then shows a recording gap as a gap, not as a line across it."""
    at = np.asarray(after, dtype=int) + 1
    return (np.insert(np.asarray(t_s, dtype=float), at, np.nan),
            np.insert(np.asarray(values, dtype=float), at, np.nan, axis=0))


def lost_stretches(camera: CameraSeries, start_mm: float | None) -> np.ndarray:
    """(K, 3): start s, end s and the insertion held (mm) of each run of lost pairs in ``camera``, in time order. A
    run ends at the next pair's time (its own last pair's when none follows); its pairs were mapped at the insertion
    last tracked before it (``start_mm``, the chain's distance, before any; NaN when that is unknown)."""
    lost = ~np.asarray(camera.tracked, dtype=bool)
    if not lost.any():
        return np.zeros((0, 3))
    edges = np.diff(np.concatenate([[0], lost.astype(np.int8), [0]]))
    first, after = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)      # run k: rows first[k] .. after[k] - 1
    t = np.asarray(camera.t_s, dtype=float)
    ends = t[np.minimum(after, len(t) - 1)]
    tracked_rows = np.flatnonzero(~lost)
    before = np.searchsorted(tracked_rows, first) - 1                           # the last tracked row before each run
    held = np.full(len(first), np.nan if start_mm is None else float(start_mm))
    known = before >= 0
    held[known] = np.asarray(camera.trocar_camera_mm, dtype=float)[tracked_rows[before[known]]]
    return np.column_stack([t[first], ends, held])


def clock_figures(path: str | Path) -> dict:
    """Whether a session's streams share one clock (issue 12), JSON-ready, seconds: where each stream ends after the
    first sample of any (``ends_s``), how far apart those ends are (``end_spread_s``), the longest step between
    frames (``max_frame_gap_s``) and the farthest any stored node is from its nearest probe fix
    (``max_node_to_fix_s``; None without nodes or fixes)."""
    with Session.open(path) as session:
        streams = {name: _rows(session.stream(name))["t_host_ns"] for name in ("frames", "probe", "imu")}
        nodes = np.array([r.time_ns for r in session.intraop_records()], dtype=np.int64)
    t0 = min((int(t.min()) for t in streams.values() if len(t)), default=0)
    ends = {name: round((int(t.max()) - t0) / 1e9, 3) for name, t in streams.items() if len(t)}
    frames, probe = np.sort(streams["frames"]), np.sort(streams["probe"])
    to_fix = None
    if len(nodes) and len(probe):
        k = np.searchsorted(probe, nodes)
        before, after = probe[np.clip(k - 1, 0, len(probe) - 1)], probe[np.clip(k, 0, len(probe) - 1)]
        to_fix = round(float(np.minimum(np.abs(nodes - before), np.abs(nodes - after)).max()) / 1e9, 3)
    return {"ends_s": ends, "end_spread_s": round(max(ends.values()) - min(ends.values()), 3) if ends else None,
            "max_frame_gap_s": round(float(np.diff(frames).max()) / 1e9, 3) if len(frames) > 1 else None,
            "nodes": int(len(nodes)), "max_node_to_fix_s": to_fix}


def fuse_imu_blocks(imu: ImuSeries, block: int = FUSION_BLOCK) -> Iterator[np.ndarray]:
    """(n, 3) yaw, pitch, roll (degrees) for consecutive blocks of ``imu``, in order.

    The filter is the live one (:class:`~snreg.imu.fusion.Fusion` at the nominal 208 Hz with its default
    settings), updated sample by sample as the acquisition does, so each step integrates over the device
    clock (with its 32-bit wrap) and the review shows the angles the operator saw.
    """
    fusion = Fusion(DEFAULT_ODR_HZ)
    for start in range(0, len(imu.t_s), block):
        stop = min(start + block, len(imu.t_s))
        yield fusion.update_block(imu.t_device_us[start:stop], imu.accel_g[start:stop], imu.gyro_dps[start:stop])


def fuse_imu(imu: ImuSeries) -> np.ndarray:
    """All of :func:`fuse_imu_blocks` at once: (N, 3) yaw, pitch, roll in degrees."""
    return np.concatenate([np.zeros((0, 3)), *fuse_imu_blocks(imu)])


def _rows(stream) -> np.ndarray:
    """A stream table in memory, up to its first unreadable block."""
    return readable_rows(stream) if isinstance(stream, h5py.Dataset) else np.asarray(stream)


def _origin(streams: dict[str, np.ndarray], node_times_ns: list[int]) -> int:
    firsts = [int(rows["t_host_ns"].min()) for rows in streams.values() if len(rows)]
    return min(firsts) if firsts else min(node_times_ns, default=0)


def _seconds(t_ns: np.ndarray, t0_ns: int) -> np.ndarray:
    return (np.asarray(t_ns, dtype=np.int64) - t0_ns) / 1e9


def _decode_rgb(jpeg: bytes) -> np.ndarray | None:
    """A JPEG snapshot as RGB (H, W, 3) uint8; None when there is none or it does not decode."""
    if not jpeg:
        return None
    bgr = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    return None if bgr is None else cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _registration(stored: StoredRegistration, intraop_ids: list[str], preop_ids: list[str] | None) -> ReviewRegistration:
    result = stored.result
    pairing = np.asarray(result.pairing, dtype=int)
    if stored.intraop_ids is None:          # written before ids were stored: the session's lists if they fit
        intraop_ids = intraop_ids if len(intraop_ids) == len(pairing) else [f"#{k}" for k in range(len(pairing))]
        fits = preop_ids is not None and len(preop_ids) > pairing.max(initial=-1)
        preop_ids = preop_ids if fits else [f"#{k}" for k in range(int(pairing.max(initial=-1)) + 1)]
    else:
        intraop_ids, preop_ids = stored.intraop_ids, stored.preop_ids
    return ReviewRegistration(stored.n, result.method, float(result.rms_mm),
                              pair_table(result, preop_ids, intraop_ids), stored.final)
