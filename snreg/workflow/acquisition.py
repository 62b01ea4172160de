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

Store SN, Store landmark, undo and the guard that refuses a store are the other half of this class, in
:mod:`snreg.workflow.node_store` (:class:`~snreg.workflow.node_store.NodeStore`).

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
from dataclasses import replace

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.camera import StereoCalibration
from snreg.chain import ChainCalibration, camera_from_probe, camera_to_trocar, trocar_from_probe
from snreg.errors import StoreError, StoreNeedsConfirmation, StoreRefused
from snreg.imu.protocol import ImuSample
from snreg.odometry import LOST, InsertionEstimate, InsertionTracker
from snreg.probe import ProbeModel
from snreg.session import Session, calibration_version
from snreg.session.schema import stereo_to_dict
from snreg.session.video import video_text
from snreg.sources import StereoFrame
from snreg.tracking import StereoTracker
from snreg.tracking.uncertainty import NodeUncertainty
from snreg.workflow.insertion import CameraInsertion, insertion_text
from snreg.workflow.node_store import NodeStore, WindowFix
from snreg.workflow.outcome import FrameOutcome, ImuReading
from snreg.workflow.pair_tracking import TrackedPair
from snreg.workflow.store_guard import StoreCheck, StoreLimits
from snreg.workflow.supervised_tracking import SupervisedTracking
from snreg.workflow.tracking_process import InlineTracking

__all__ = ["Acquisition", "FrameOutcome", "ImuReading", "StoreLimits", "StoreCheck", "StoreError", "StoreRefused",
           "StoreNeedsConfirmation", "THESIS_FIXES_PER_NODE"]

THESIS_FIXES_PER_NODE = 60
STILL_SPREAD_MM = 1.0           # the store window counts as "held still" below this spread (RMS about the median)
VIDEO_START_WAIT_S = 10.0        # for the video encoder to start before the first frame (it runs in its own process)
INSERTION_ENDED = "no longer tracked since the tracking process ended"   # a lost pair's reason after its death


class Acquisition(NodeStore):
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
        self._fixes: deque[WindowFix] = deque(maxlen=self.fixes_per_node)
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
            self._fixes.append(WindowFix(fix.tip, fix.axis, tip_trocar, quat, float(imu.gap_s), imu.state, frame.t_left_ns,
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

    def _record_imu(self, samples: Sequence[ImuSample]) -> None:
        if not samples:
            return
        self.session.append_imu(np.array([s.t_host_ns for s in samples], dtype=np.int64),
                                np.array([s.t_device_us for s in samples], dtype=np.int64) * 1000,
                                np.array([s.accel_g for s in samples]), np.array([s.gyro_dps for s in samples]))

