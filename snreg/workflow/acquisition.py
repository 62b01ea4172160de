"""Acquisition: each stereo pair into a probe fix in the camera and trocar frames, the streams into the
session, and Store SN, undo and auto-store over the last valid fixes, guarded.

Why here and not in the GUI: the app's worker thread and ``snreg demo --headless`` must run the very same
steps (docs/design.md, Habits: real and simulated devices share the code after the sources). A node is the median
of the last N valid tip fixes (thesis §5.2: N = 60) in both frames, with their spread; each fix is mapped with
the IMU orientation at its own frame's grab time (:class:`ImuReading`). Each node also carries its own error's
covariance (trocar frame, :func:`~snreg.tracking.uncertainty.node_covariance`: the stereo geometry at its depth, the
tracker's residual and the window's spread, the probe's pointing, the IMU at its lever and the insertion), computed at
the store from the window's fixes and the node's orientation and insertion, and kept by source (``error_sources``: what
the app advises improving).

A store is refused, with the reason in words and on record in the session's events (``store_refused``), when the
window is not full, its newest fix is stale (the probe is out of view), the IMU is absent or stale (unless the
acquisition runs without an IMU by choice) or the window spreads over the limit (:class:`StoreLimits`, 2 mm by
default); a store within ``duplicate_mm`` of a stored node needs ``confirmed=True``
(:class:`~snreg.errors.StoreNeedsConfirmation` names that node). Auto-store keeps its stricter rule (held still
within ``STILL_SPREAD_MM``, over ``AUTO_STORE_SEPARATION_MM`` from every stored node and landmark) on top of the guard.

Store landmark (issue 29) stores the window as an anatomical landmark (kind ``landmark``, id = its name, provenance as
a node's) under the same guard; a landmark of that name already stored asks first, and confirmed, the new one replaces
it (the old stays on record: journal, ``landmark_replaced`` event). Undo takes back the last stored, node or landmark.

With insertion tracking (``insertion``, issue 27) each pair is mapped with the chain at the camera's insertion at that
pair (:class:`~snreg.workflow.insertion.CameraInsertion`), the insertion goes to ``streams/camera`` and a node
records the median insertion of its window. While the insertion is lost and the camera may have moved since it was
last tracked, Store SN is refused as well, but that refusal alone may be overridden (``store(override=True)``: the
node is stored and a ``store_override`` event keeps the reason); auto-store never overrides.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.camera import StereoCalibration
from snreg.chain import ChainCalibration, camera_from_probe, camera_to_trocar, trocar_from_probe
from snreg.errors import StoreError, StoreNeedsConfirmation, StoreRefused
from snreg.imu.protocol import ImuSample
from snreg.landmarks import LANDMARK, NODE, landmark_name
from snreg.odometry import LOST, InsertionEstimate, InsertionTracker
from snreg.probe import ProbeModel
from snreg.session import IntraopNode, Session, calibration_version
from snreg.session.schema import stereo_to_dict
from snreg.session.video import video_text
from snreg.sources import StereoFrame
from snreg.tracking import StereoTracker, summarise
from snreg.tracking.uncertainty import NodeUncertainty, node_covariance_sources, summed_covariance
from snreg.workflow.insertion import CameraInsertion, insertion_text
from snreg.workflow.outcome import FrameOutcome, ImuReading
from snreg.workflow.pair_tracking import TrackedPair
from snreg.workflow.store_guard import StoreCheck, StoreLimits, nearest_node, same_landmark
from snreg.workflow.supervised_tracking import SupervisedTracking
from snreg.workflow.tracking_process import InlineTracking

__all__ = ["Acquisition", "FrameOutcome", "ImuReading", "StoreLimits", "StoreCheck", "StoreError", "StoreRefused",
           "StoreNeedsConfirmation", "THESIS_FIXES_PER_NODE", "IMU_ABSENT"]

THESIS_FIXES_PER_NODE = 60
STILL_SPREAD_MM = 1.0           # the store window counts as "held still" below this spread (RMS about the median)
AUTO_STORE_SEPARATION_MM = 10.0  # auto-store only this far from every stored node: one node per rest
IMU_ABSENT = "absent"            # the IMU state of a rig run without one (chosen in the device dialog)
VIDEO_START_WAIT_S = 10.0        # for the video encoder to start before the first frame (it runs in its own process)
INSERTION_ENDED = "no longer tracked since the tracking process ended"   # a lost pair's reason after its death


@dataclass(frozen=True, eq=False)
class _Fix:
    camera: np.ndarray
    axis: np.ndarray       # the probe's axis, camera frame
    trocar: np.ndarray
    quat_xyzw: np.ndarray
    imu_gap_s: float
    imu_state: str
    grabbed_ns: int        # its frame's (left) grab time: the stream rows' clock
    seen_ns: int           # host time it was computed
    insertion_mm: float    # the camera's insertion it was mapped with (NaN: the chain's own, tracking off)
    insertion_sd_mm: float  # that insertion's change's sd since the start (tracked or held; NaN: tracking off)


class Acquisition:
    """Tracks pairs, keeps the last ``fixes_per_node`` valid fixes, records streams and stores nodes in ``session``.

    ``imu_required``: False only when the acquisition runs without an IMU by choice (stores are then not refused
    for it); ``clock``: host time in ns (tests pass their own). ``video_fps``: record both feeds into the session's
    video at this nominal rate (None: no video); a segment the session is recording already goes on.
    ``insertion``: track the camera's insertion with it (its start: the trocar calibration's distance, normally);
    None keeps the chain's constant distance. A :class:`~snreg.workflow.insertion.CameraInsertion` an earlier
    acquisition followed on the same calibration and chain (the app restarting its worker) goes on from where it
    stopped: its keyframes, the last insertion tracked and when, so a camera that slid meanwhile is not taken to be
    back at the start. ``uncertainty``: the magnitudes each stored node's covariance is made of (their cited
    defaults unless given). ``tracking_process``: the pairs are tracked in a process of their own
    (:class:`~snreg.workflow.tracking_process.TrackingProcess`: the live app, so its GUI thread never waits for the
    trackers' GIL), the same steps as in this thread (the default), restarted when it dies
    (:class:`~snreg.workflow.supervised_tracking.SupervisedTracking`: each death in ``tracking_problem``, counted in
    ``tracking_stops``); :meth:`close` ends it.
    """

    def __init__(self, calibration: StereoCalibration, probe: ProbeModel, chain: ChainCalibration, session: Session,
                 *, fixes_per_node: int = THESIS_FIXES_PER_NODE, limits: StoreLimits = StoreLimits(),
                 imu_required: bool = True, clock: Callable[[], int] = time.perf_counter_ns,
                 video_fps: float | None = None, insertion: InsertionTracker | CameraInsertion | None = None,
                 uncertainty: NodeUncertainty = NodeUncertainty(), tracking_process: bool = False):
        self.tracker = StereoTracker(calibration, probe)
        self.tracking_problem = ""                 # the tracking process's last death, in words ("" while none)
        self.tracking_stops = 0                    # its deaths so far
        self.uncertainty = uncertainty
        self.chain, self.session, self.limits, self.imu_required = chain, session, limits, bool(imu_required)
        self.insertion = CameraInsertion(insertion, chain) if isinstance(insertion, InsertionTracker) else insertion
        self.stereo_version = calibration_version(stereo_to_dict(calibration))
        self.chain_version = calibration_version(chain.to_dict())
        self.fixes_per_node = max(1, int(fixes_per_node))
        self._clock = clock
        self._fixes: deque[_Fix] = deque(maxlen=self.fixes_per_node)
        self._last_reason = ""
        self._last_imu: ImuReading | None = None
        self._in_flight: deque[tuple[StereoFrame, ImuReading]] = deque()     # pairs begun, not finished
        tracked_insertion = None if self.insertion is None else self.insertion.tracker
        self._tracking = (SupervisedTracking(self.tracker, calibration, probe, tracked_insertion) if tracking_process
                          else InlineTracking(self.tracker, tracked_insertion))
        self._stored_here: list[str] = []          # ids stored through this object, for undo
        self.error_sources: dict[str, dict] = {}   # node id -> its covariance by source (nodes stored here)
        self.video_fps, self.video_problem = video_fps, "" if video_fps else "off"
        if not video_fps and session.writable and session.video_state() is not None:
            session.stop_video()                   # recording was turned off: the segment recorded so far is closed
        elif video_fps and session.writable and session.video_state() is None:
            self._start_video(*calibration.image_size, wait_s=VIDEO_START_WAIT_S)

    def set_fixes_per_node(self, n: int) -> None:
        """Store the median of the last ``n`` valid fixes (thesis: 60); keeps the fixes already collected."""
        self.fixes_per_node = max(1, int(n))
        self._fixes = deque(self._fixes, maxlen=self.fixes_per_node)

    def set_max_spread(self, mm: float) -> None:
        """Refuse manual stores whose window spreads over ``mm`` from now on."""
        self.limits = replace(self.limits, max_spread_mm=float(mm))

    def process(self, frame: StereoFrame, imu: ImuReading) -> FrameOutcome:
        """Track one pair at the IMU orientation of its grab time (and the camera's insertion at it, when tracked),
        record the frame, probe, IMU and camera streams (the probe and camera rows at the frame's own time), update
        the window: :meth:`begin` and :meth:`finish` of the same pair."""
        self.begin(frame, imu)
        return self.finish()

    def begin(self, frame: StereoFrame, imu: ImuReading) -> None:
        """Record the pair's IMU samples and frame row (and video) and hand it to the trackers; :meth:`finish` gives
        its outcome. With a tracking process the pair is tracked there while the caller goes on (read and begin
        the next pair, say): outcomes come back in the order pairs were begun."""
        self._record_imu(imu.samples)
        self._record_frame(frame)
        self._in_flight.append((frame, imu))
        try:
            self._tracking.submit(frame.left, frame.right, imu.earth_from_imu)
        except BaseException:
            self._in_flight.pop()              # tracked here, it raised (a pair of another size): never begun
            raise

    @property
    def in_flight(self) -> int:
        """Pairs begun and not finished yet."""
        return len(self._in_flight)

    def ready(self) -> bool:
        """The oldest pair begun has been tracked (:meth:`finish` returns at once)."""
        return bool(self._in_flight) and self._tracking.ready()

    def finish(self) -> FrameOutcome:
        """The outcome of the oldest pair begun (waiting for its tracking): its probe fix mapped into the trocar
        frame at its IMU orientation and insertion, its probe and camera rows recorded, the store window updated."""
        frame, imu = self._in_flight.popleft()
        try:
            tracked = self._tracking.result()          # its error (a pair of another size) is raised here
        finally:
            self._note_tracking()
        self._last_imu = imu
        fix, reason, tip_trocar, pose = tracked.fix, tracked.reason, None, None
        self._last_reason = reason
        step = self._follow_insertion(frame, imu, tracked)
        chain = self.chain if step is None else step.chain
        if fix is not None:
            tip_trocar = camera_to_trocar(chain, imu.earth_from_imu, fix.tip)
            pose = trocar_from_probe(chain, imu.earth_from_imu, camera_from_probe(fix.tip, fix.axis))
            quat = Rotation.from_matrix(imu.earth_from_imu).as_quat()
            # the insertion's change since the start (the trocar calibration's own error is a term of its own): the
            # tracker's when tracked, grown with the time lost and the turn since when held (snreg.odometry.held)
            slide = float("nan") if step is None else step.change_sd_mm
            self._fixes.append(_Fix(fix.tip, fix.axis, tip_trocar, quat, float(imu.gap_s), imu.state, frame.t_left_ns,
                                    self._clock(), float("nan") if step is None else step.used_mm, slide))
            self.session.append_probe(frame.t_left_ns, frame.t_right_ns, fix.tip, fix.centre, fix.axis, fix.quality)
        window = self._window_trocar()
        spread = window.spread_mm if window is not None else float("nan")
        still = bool(spread <= STILL_SPREAD_MM)
        check = self.check_store(window)
        due = still and not check.refusal and self._away_from_stored(window.xyz)
        return FrameOutcome(frame.index, fix, reason, tip_trocar, len(self._fixes), spread, still, due,
                            tracked.track_ms, pose, check, float(imu.gap_s),
                            video_text(self.session.video_state(), self.video_problem), step,
                            insertion_text(step, self.insertion.start_mm) if step else "", tracked.insertion_ms)

    def _follow_insertion(self, frame: StereoFrame, imu: ImuReading, tracked: TrackedPair):
        """The insertion at this pair, its ``streams/camera`` row recorded; None without tracking. Lost, in words,
        once a tracking process died (its keyframes went with it)."""
        if self.insertion is None:
            return None
        estimate = tracked.estimate
        if estimate is None:
            estimate = InsertionEstimate(frame.index, LOST, float("nan"), 0.0, float("nan"), float("nan"),
                                         INSERTION_ENDED)
        step = self.insertion.step(estimate, frame.t_left_ns, imu.earth_from_imu)
        self.session.append_camera(frame.t_left_ns, frame.t_right_ns, estimate.trocar_camera_mm, estimate.state,
                                   estimate.quality, estimate.residual_mm, estimate.sd_mm)
        return step

    def _note_tracking(self) -> None:
        """A death of the tracking process (:mod:`~snreg.workflow.supervised_tracking`: restarted, or tracking here
        for good) said in ``tracking_problem`` and put on record (``tracking_process_stopped``) once each."""
        stops = getattr(self._tracking, "stops", 0)
        if stops != self.tracking_stops:
            self.tracking_stops, self.tracking_problem = stops, self._tracking.problem
            self.session.log_event("tracking_process_stopped", reason=self.tracking_problem,
                                   restarted=self._tracking.pid is not None)

    @property
    def tracking_pid(self) -> int | None:
        """The tracking process's id (None when pairs are tracked in this process)."""
        return self._tracking.pid

    @property
    def tracking_answering(self) -> bool:
        """Pairs are tracked in a tracking process now (False in this process, and while a restarted one starts)."""
        return bool(getattr(self._tracking, "answering", False))

    def close(self) -> None:
        """Finish the pairs in flight (their rows recorded, their outcomes dropped) and end the tracking process; the
        insertion tracker it followed comes back into :attr:`insertion` (a later acquisition goes on with it)."""
        while self._in_flight:
            self.finish()
        tracker = self._tracking.close()
        if self.insertion is not None and tracker is not None:
            self.insertion.tracker = tracker
        self._tracking = InlineTracking(self.tracker, None if self.insertion is None else self.insertion.tracker)

    def _start_video(self, width: int, height: int, wait_s: float = 0.0) -> None:
        try:
            self.session.start_video(self.video_fps, width, height, wait_s=wait_s)
        except OSError as err:
            self.video_problem = str(err)
            self.session.log_event("video_not_recorded", reason=self.video_problem)

    def _record_frame(self, frame: StereoFrame) -> None:
        """The frame row, with the pair into the session's video when it is recorded (started with this object, at
        the calibration's image size; a session whose recording was closed meanwhile starts a new one here)."""
        if not self.video_problem and self.session.video_state() is None:
            self._start_video(frame.left.shape[1], frame.left.shape[0])
        if self.session.video_state() is not None:
            self.session.append_frame_pair(frame.t_left_ns, frame.t_right_ns, frame.index, frame.left, frame.right)
        else:
            self.session.append_frames(frame.t_left_ns, frame.t_right_ns, frame.index)

    def check_store(self, window=None) -> StoreCheck:
        """Whether Store SN would store now, and if not why (in words); the near node when one is. ``window``: the
        store window's summary when the caller has it already."""
        return self._check(window, lambda here: nearest_node(self.session.intraop_records(), here,
                                                             self.limits.duplicate_mm))

    def check_landmark(self, name: str, window=None) -> StoreCheck:
        """Whether Store landmark would store ``name`` now: Store SN's guard, and the landmark of that name when one
        is stored (``near``, to ask about first)."""
        return self._check(window, lambda here: same_landmark(self.session.intraop_records(LANDMARK), name, here))

    def _check(self, window, near: Callable[[np.ndarray], StoreCheck]) -> StoreCheck:
        """The guard's refusal in words, else ``near`` at the window's median (with the insertion's overridable
        refusal when the camera may have moved)."""
        n, needed = len(self._fixes), self.fixes_per_node
        if n < needed:
            return StoreCheck(f"only {n} of {needed} valid fixes so far; hold the probe on the node")
        age_s = (self._clock() - self._fixes[-1].seen_ns) / 1e9
        if age_s > self.limits.fix_stale_s:
            lost = f" ({self._last_reason})" if self._last_reason else ""
            return StoreCheck(f"the last valid fix is {age_s:.1f} s old{lost}: the probe is not tracked now; "
                              "bring it into view and hold it on the node")
        imu_problem = self._imu_problem()
        if imu_problem:
            return StoreCheck(imu_problem)
        window = window or self._window_trocar()
        if window.spread_mm > self.limits.max_spread_mm:
            return StoreCheck(f"the probe moved: the last {needed} fixes spread {window.spread_mm:.1f} mm (limit "
                              f"{self.limits.max_spread_mm:.1f} mm); hold it still on the node")
        found = near(window.xyz)
        moved = self.insertion.store_refusal() if self.insertion is not None else ""
        return replace(found, refusal=moved, overridable=True) if moved else found

    def store(self, node_id: str, label: str, *, counts: float = float("nan"), left_jpeg=b"", right_jpeg=b"",
              confirmed: bool = False, trigger: str = "", override: bool = False) -> IntraopNode:
        """The median of the store window as node ``node_id``, durable on return, with the camera-frame tip, the mean
        IMU orientation, the calibration versions and the median insertion it was mapped with; its time is its newest
        fix's grab time (on the streams' clock: the node points at its own probe rows, however late the store was
        asked). Refused (:class:`StoreRefused`, put on record with ``trigger``, e.g. "F5") as :meth:`check_store`
        says, unless the refusal is overridable and ``override`` is True (the node is stored and a ``store_override``
        event keeps the refusal); :class:`StoreNeedsConfirmation` when a stored node is near and ``confirmed`` is
        False. Snapshots are JPEG bytes or BGR images."""
        return self._store(self.check_store(), str(node_id), label, NODE, counts, left_jpeg, right_jpeg, confirmed,
                           trigger, override)

    def store_landmark(self, name: str, *, left_jpeg=b"", right_jpeg=b"", confirmed: bool = False, trigger: str = "",
                       override: bool = False) -> IntraopNode:
        """The median of the store window as the anatomical landmark ``name`` (kind landmark, id = the name as
        :func:`~snreg.landmarks.landmark_name` keeps it), stored and guarded as :meth:`store` stores a node;
        :class:`StoreError` when the name is missing or not a landmark name; :class:`StoreNeedsConfirmation` when a
        landmark of that name is stored and ``confirmed`` is False; confirmed, this one replaces it."""
        try:
            name = landmark_name(name)
        except ValueError as err:
            raise StoreError(f"{err}; pick one of the preop landmarks or type its name") from None
        return self._store(self.check_landmark(name), name, "", LANDMARK, float("nan"), left_jpeg, right_jpeg,
                           confirmed, trigger, override)

    def _store(self, check: StoreCheck, node_id: str, label: str, kind: str, counts: float, left_jpeg, right_jpeg,
               confirmed: bool, trigger: str, override: bool) -> IntraopNode:
        """Store the window as ``node_id`` of ``kind`` once ``check`` allows it (refusals and confirmations as
        :meth:`store` says; a confirmed landmark replaces the stored one of its name)."""
        overriding = bool(check.refusal) and check.overridable and override
        if check.refusal and not overriding:
            self.session.log_event("store_refused", reason=check.refusal, trigger=str(trigger), node_id=node_id,
                                   **({"overridable": True} if check.overridable else {}),
                                   **({"landmark": True} if kind == LANDMARK else {}))
            raise StoreRefused(check.refusal, overridable=check.overridable)
        if check.near is not None and not confirmed:
            raise StoreNeedsConfirmation(check.question, check.near.id)
        if kind == LANDMARK and check.near is not None:
            self.session.remove_intraop_node(node_id)
            self.session.log_event("landmark_replaced", node_id=node_id, distance_mm=round(check.near_mm, 2),
                                   old_xyz_trocar=[round(float(v), 3) for v in check.near.xyz_trocar],
                                   trigger=str(trigger))
        camera = summarise(np.array([f.camera for f in self._fixes]))
        trocar = summarise(np.array([f.trocar for f in self._fixes]))
        orientation = Rotation.from_quat(np.array([f.quat_xyzw for f in self._fixes])).mean().as_matrix()
        insertion = float(np.median([f.insertion_mm for f in self._fixes]))
        sources = self._covariance_sources(camera.xyz, orientation, insertion)
        node = self.session.add_intraop_node(node_id, label, trocar.xyz, xyz_camera=camera.xyz,
                                             spread_mm=trocar.spread_mm, n_frames=trocar.n_frames, counts=counts,
                                             time_ns=self._fixes[-1].grabbed_ns, left_jpeg=left_jpeg,
                                             right_jpeg=right_jpeg, earth_from_imu=orientation,
                                             stereo_version=self.stereo_version, chain_version=self.chain_version,
                                             trocar_camera_mm=insertion,
                                             cov_trocar_mm2=summed_covariance(sources), kind=kind)
        if overriding:
            self.session.log_event("store_override", node_id=node.id, reason=check.refusal, trigger=str(trigger))
        if check.near is not None and kind == NODE:
            self.session.log_event("store_near_confirmed", node_id=node.id, near=check.near.id,
                                   distance_mm=round(check.near_mm, 2), trigger=str(trigger))
        self._stored_here.append(node.id)
        self.error_sources[node.id] = sources
        return node

    def _covariance_sources(self, tip_camera: np.ndarray, earth_from_imu: np.ndarray, insertion_mm: float) -> dict:
        """The store window's node covariance by source ((3, 3) mm^2 each, trocar frame), at its insertion's chain."""
        axes = np.array([f.axis for f in self._fixes])
        chain = self.chain if not np.isfinite(insertion_mm) else self.chain.with_insertion(insertion_mm)
        slide = np.array([f.insertion_sd_mm for f in self._fixes])
        return node_covariance_sources(self.uncertainty, self.tracker.calibration, self.tracker.probe, chain,
                                       earth_from_imu, tip_camera, axes.mean(axis=0),
                                       window_camera=np.array([f.camera for f in self._fixes]),
                                       insertion_sd_mm=float(np.median(slide)) if np.isfinite(slide).all() else None)

    def undo(self) -> IntraopNode:
        """Take back the node or landmark stored last (in this run, else the session's last); :class:`StoreError` if
        none. A landmark that replaced another is taken back alone: the one it replaced stays on record only."""
        stored = [n.id for n in self.session.intraop_records(kind=None)]
        while self._stored_here and self._stored_here[-1] not in stored:
            self._stored_here.pop()
        target = self._stored_here.pop() if self._stored_here else (stored[-1] if stored else None)
        if target is None:
            raise StoreError("there is no stored node to undo")
        return self.session.remove_intraop_node(target)

    def _imu_problem(self) -> str:
        """Why the window's trocar positions cannot be trusted for want of an IMU, in words; "" when they can."""
        if not self.imu_required:
            return ""
        readings = [(f.imu_state, f.imu_gap_s) for f in self._fixes]
        if self._last_imu is not None:
            readings.append((self._last_imu.state, self._last_imu.gap_s))
        if any(state == IMU_ABSENT for state, _ in readings):
            return ("there is no IMU, so the tip cannot be followed into the trocar frame; connect the IMU, "
                    "or start the session without one (Devices: IMU none)")
        state, gap = max(readings, key=lambda r: r[1])
        if gap > self.limits.imu_stale_s:
            return (f"the IMU is stale: no sample within {gap:.1f} s of a frame (IMU {state}), so the tip cannot be "
                    "mapped into the trocar frame; reconnect the IMU and store again")
        return ""

    def _away_from_stored(self, here: np.ndarray) -> bool:
        """Auto-store rule, for a full and still window with median ``here``: away from every stored node and landmark
        (the probe resting on a landmark just stored is not a new node)."""
        stored = [node.xyz_trocar for node in self.session.intraop_records(kind=None)]
        return not stored or float(np.min(np.linalg.norm(np.array(stored) - here, axis=1))) > AUTO_STORE_SEPARATION_MM

    def _window_trocar(self):
        """Median and spread of the full store window in the trocar frame; None until full."""
        if len(self._fixes) < self.fixes_per_node:
            return None
        return summarise(np.array([f.trocar for f in self._fixes]))

    def _record_imu(self, samples: Sequence[ImuSample]) -> None:
        if not samples:
            return
        self.session.append_imu(np.array([s.t_host_ns for s in samples], dtype=np.int64),
                                np.array([s.t_device_us for s in samples], dtype=np.int64) * 1000,
                                np.array([s.accel_g for s in samples]), np.array([s.gyro_dps for s in samples]))

