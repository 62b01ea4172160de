"""The acquisition worker: reads frame pairs and runs :class:`snreg.workflow.acquisition.Acquisition` on them.

Why: capture, tracking and session writes must never run on the GUI thread (docs/design.md, Habits). The worker
lives in its own QThread, paced by a timer there; every frame ends as one :class:`FrameResult` signal,
and "Store SN" (or Store landmark) and undo requests arrive as queued slot calls between frames, so a node is the median
of fixes this worker itself kept. The core decides whether a store is refused (said in ``store_failed``) or
must be confirmed first (``store_confirm``: the question naming the near node, and the request to send back with
``confirmed=True``). A refusal the operator may override (the camera's insertion lost after the camera moved) is
offered instead (``store_override_offered``: the refusal and the request to send back with ``override=True``), unless
auto-store asked: auto-store never overrides. Connect the signals before :func:`start_worker`.

With ``track_insertion`` the camera's insertion is followed too (:class:`~snreg.odometry.InsertionTracker`, built
here: its cost never lands on the GUI thread), from the trocar calibration's distance, or from where
``resume_insertion`` (what an earlier worker followed on the same calibration and chain) left it.

Where the pairs are tracked (issue 36): with ``tracking_process`` (the app's) the probe tracker and the insertion
tracker run in a process of their own (:class:`~snreg.workflow.tracking_process.TrackingProcess`), so their Python
never holds the GIL the GUI thread waits for, and the worker reads and records the next pair while one is tracked
(``AHEAD`` pairs in flight at most; every pair's result is emitted in frame order, once it is back). The insertion
tracker comes back from that process when the worker stops, for :attr:`AcquisitionWorker.kept_insertion`. A tracking
process that dies is restarted (:mod:`snreg.workflow.supervised_tracking`: its pairs meanwhile tracked in this
thread, and for good after repeated deaths), each death said once in ``store_failed``; without ``tracking_process``
each pair is tracked here as it is read.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from PySide6.QtCore import QCoreApplication, QMetaObject, QObject, Qt, QThread, QTimer, Signal, Slot

from snreg import geometry
from snreg.camera import StereoCalibration
from snreg.chain import ChainCalibration
from snreg.imu.monitor import ImuMonitor, ImuSnapshot
from snreg.odometry import InsertionTracker
from snreg.session import Session, SessionError
from snreg.sources import FrameSource, SourceError, SourceState
from snreg.workflow.acquisition import (THESIS_FIXES_PER_NODE, Acquisition, FrameOutcome, ImuReading, StoreError,
                                        StoreLimits, StoreNeedsConfirmation, StoreRefused)
from snreg.workflow.display import DISPLAY_SCALE, display_rgb
from snreg.workflow.insertion import CameraInsertion
from snreg.workflow.node_store import IMU_ABSENT
from snreg.workflow.navigation import NavigationState, navigate, trocar_from_camera_at
from snreg_gui.acquisition.hot_spots import feed_layer, guidance_text

_AXIS_DRAWN_MM = 50.0
AHEAD = 1              # pairs tracked in the tracking process while the worker reads the next (module docstring)


@dataclass(frozen=True, eq=False)
class FrameResult:
    """One processed pair for display: RGB images, the core's outcome, where to draw the probe, stream health.

    Images and overlays are at ``DISPLAY_SCALE`` of the camera resolution.
    ``overlay_left``/``overlay_right``: (2, 2) display pixels of the tip and of a point ``_AXIS_DRAWN_MM`` up the
    axis, None without a fix.
    """

    outcome: FrameOutcome
    left_rgb: np.ndarray
    right_rgb: np.ndarray
    overlay_left: np.ndarray | None
    overlay_right: np.ndarray | None
    imu: ImuSnapshot
    skew_ms: float
    fps: float
    t_host_ns: int
    hot_spots_left: object = None          # HotSpotLayer: the hot spots not found yet on each feed (display pixels)
    hot_spots_right: object = None
    guidance: str = ""                     # the way to the nearest in the view's words, or why none is given


@dataclass(frozen=True)
class StoreRequest:
    """Store SN as asked for on screen; the id is the session's next free ``SN<k>``. ``trigger``: what asked
    ("button", "Space", "F5", "auto"), kept on record with a refusal; ``confirmed``: the technician said yes to
    storing near a stored node (a landmark: to replacing the stored one of its name); ``override``: the technician
    chose "Store anyway" over an overridable refusal. ``landmark``: Store landmark of that name instead (the same
    guards; ``label`` and ``counts`` unused)."""

    label: str
    counts: float = float("nan")
    trigger: str = "button"
    confirmed: bool = False
    override: bool = False
    landmark: str = ""

    def confirm(self) -> "StoreRequest":
        return replace(self, confirmed=True)

    def overriding(self) -> "StoreRequest":
        return replace(self, override=True)


@dataclass(frozen=True, eq=False)
class KeptInsertion:
    """The camera's insertion a stopped worker followed, and the calibration and chain it followed it on: a later
    worker on the very same two goes on with it (a wizard's new calibration is a new object, and starts again)."""

    calibration: StereoCalibration
    chain: ChainCalibration
    insertion: CameraInsertion

    def on(self, calibration: StereoCalibration, chain: ChainCalibration) -> CameraInsertion | None:
        """The insertion to go on with under ``calibration`` and ``chain``; None when either is another."""
        return self.insertion if calibration is self.calibration and chain is self.chain else None


class AcquisitionWorker(QObject):
    """Frame loop, node store and undo. ``make_source`` runs in the worker thread (a renderer may take time to build);
    ``record_video``: both feeds go into the session's video (its encoder works in a process of its own);
    ``track_insertion``, ``resume_insertion``: follow the camera's insertion; ``tracking_process``: track the pairs in
    a process of their own (module docstring)."""

    frame_processed = Signal(object)     # FrameResult
    node_stored = Signal(object)         # snreg.session.IntraopNode
    node_error_sources = Signal(str, object)   # a stored node's id, its covariance by source (advice on improving)
    node_removed = Signal(object)        # snreg.session.IntraopNode taken back by undo
    store_failed = Signal(str)           # one sentence saying what to do
    store_confirm = Signal(str, object)  # the question naming the near node, the StoreRequest to confirm
    store_override_offered = Signal(str, object)   # an overridable refusal, the StoreRequest to send back overriding
    source_stopped = Signal(str)         # the source's problem

    def __init__(self, make_source: Callable[[], FrameSource], calibration: StereoCalibration, probe,
                 chain: ChainCalibration, imu: ImuMonitor, session: Session, fps: float,
                 fixes_per_node: int = THESIS_FIXES_PER_NODE, limits: StoreLimits = StoreLimits(),
                 record_video: bool = True, *, track_insertion: bool = False,
                 resume_insertion: CameraInsertion | None = None, tracking_process: bool = True):
        super().__init__()
        self._make_source, self._imu, self._fps, self._record_video = make_source, imu, fps, record_video
        self._track_insertion, self._resume_insertion = track_insertion, resume_insertion
        self._tracking_process = tracking_process
        self._pending: deque[tuple] = deque()     # per pair begun, not emitted yet: (frame, IMU snapshot, reading, ns)
        self._tracking_said = 0                  # the tracking process's deaths said so far
        self._setup = (calibration, probe, chain, session, fixes_per_node, limits)
        self.acquisition: Acquisition | None = None
        self._source: FrameSource | None = None
        self._timer: QTimer | None = None
        self._last_frame = None
        self._last_ns: int | None = None
        self._fps_measured = 0.0
        self._navigation = NavigationState()

    @Slot()
    def start(self) -> None:
        calibration, probe, chain, session, fixes, limits = self._setup
        without_imu = self._imu.snapshot().state == IMU_ABSENT      # no IMU port chosen in the device dialog
        insertion = (self._resume_insertion or InsertionTracker(calibration, chain, probe=probe)
                     if self._track_insertion else None)
        self.acquisition = Acquisition(calibration, probe, chain, session, fixes_per_node=fixes, limits=limits,
                                       imu_required=not without_imu,
                                       video_fps=self._fps if self._record_video else None, insertion=insertion,
                                       tracking_process=self._tracking_process)
        try:
            session.log_event("acquisition_started", imu="none (chosen)" if without_imu else "required",
                              insertion=self._insertion_started(),
                              stereo_version=self.acquisition.stereo_version,
                              chain_version=self.acquisition.chain_version, max_spread_mm=limits.max_spread_mm)
        except (SessionError, OSError) as err:
            self.store_failed.emit(f"The session cannot be written: {err}")
        try:
            self._source = self._make_source()
        except (SourceError, OSError, ValueError) as err:
            self.source_stopped.emit(str(err))
            return
        self._timer = QTimer(self)
        self._timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._timer.timeout.connect(self._step)
        self._timer.start(round(1000 / self._fps))

    def _insertion_started(self) -> str:
        """How this run follows the camera's insertion, for the record."""
        if self.acquisition.insertion is None:
            return "not tracked"
        resumed = self.acquisition.insertion.last
        return (f"tracked, from {self.acquisition.insertion.start_mm:.1f} mm" if resumed is None else
                f"tracked, resumed at {resumed.used_mm:.1f} mm")

    @property
    def kept_insertion(self) -> KeptInsertion | None:
        """What this worker followed of the camera's insertion (None without tracking); read it once it stopped."""
        if self.acquisition is None or self.acquisition.insertion is None:
            return None
        calibration, _, chain, *_ = self._setup
        return KeptInsertion(calibration, chain, self.acquisition.insertion)

    @Slot()
    def stop(self) -> None:
        """Stop the frame loop and hand this object back to the GUI thread, which deletes it later."""
        if self._timer is not None:
            self._timer.stop()
        if self._source is not None:
            self._source.close()
        if self.acquisition is not None:        # the pairs in flight recorded (not shown), the tracking process
            self._pending.clear()               # ended, its insertion tracker back in ours (kept_insertion)
            try:
                self.acquisition.close()
            except (SessionError, OSError, ValueError) as err:
                self.store_failed.emit(f"The last pairs were not recorded: {err}")
        self.moveToThread(QCoreApplication.instance().thread())

    @Slot(int)
    def set_fixes_per_node(self, n: int) -> None:
        """Store the median of the last ``n`` valid fixes (thesis: 60)."""
        if self.acquisition is not None:
            self.acquisition.set_fixes_per_node(n)

    @Slot(float)
    def set_max_spread(self, mm: float) -> None:
        """Refuse stores whose window spreads over ``mm`` from now on (the app's setting)."""
        if self.acquisition is not None:
            self.acquisition.set_max_spread(mm)

    @Slot(object)
    def store_node(self, request: StoreRequest) -> None:
        """Median and spread of the store window into the session (durable on return), as a node or (``request.
        landmark``) a landmark, with the last frame as snapshots; or the refusal in words, or the question to
        confirm."""
        left, right = (self._last_frame.left, self._last_frame.right) if self._last_frame is not None else (b"", b"")
        asked = dict(left_jpeg=left, right_jpeg=right, confirmed=request.confirmed, trigger=request.trigger,
                     override=request.override)
        try:
            node = (self.acquisition.store_landmark(request.landmark, **asked) if request.landmark else
                    self.acquisition.store(self.acquisition.session.next_node_id(), request.label,
                                           counts=request.counts, **asked))
        except StoreNeedsConfirmation as err:
            self.store_confirm.emit(str(err), request)
            return
        except StoreRefused as err:
            if err.overridable and request.trigger != "auto":
                self.store_override_offered.emit(str(err), request)
            else:
                self.store_failed.emit(f"Refused ({request.trigger}): {err}.")
            return
        except StoreError as err:
            self.store_failed.emit(f"Not stored: {err}.")
            return
        except (SessionError, OSError) as err:
            self.store_failed.emit(f"The node was not stored: {err}")
            return
        self.node_stored.emit(node)
        self.node_error_sources.emit(node.id, self.acquisition.error_sources[node.id])

    @Slot()
    def undo(self) -> None:
        """Take back the node or landmark stored last."""
        try:
            node = self.acquisition.undo()
        except (StoreError, SessionError, OSError) as err:
            self.store_failed.emit(f"Nothing undone: {err}.")
            return
        self.node_removed.emit(node)

    @Slot()
    def _step(self) -> None:
        self._emit_tracked(ahead=AHEAD, wait=False)        # pairs tracked meanwhile
        frame = self._source.read()
        if frame is None and self._source.state is SourceState.OPEN:
            return                               # none this tick (a camera that missed a grab)
        if frame is None:
            self._timer.stop()
            self._emit_tracked(ahead=0)
            self.source_stopped.emit(self._source.problem)
            return
        now = time.perf_counter_ns()
        if self._last_ns is not None:
            instant = 1e9 / max(now - self._last_ns, 1)
            self._fps_measured = instant if self._fps_measured == 0 else 0.9 * self._fps_measured + 0.1 * instant
        self._last_ns, self._last_frame = now, frame
        imu = self._imu.snapshot()
        reading = ImuReading.at_frame(self._imu, frame)
        self.acquisition.begin(frame, reading)
        self._pending.append((frame, imu, reading, now))
        self._emit_tracked(ahead=AHEAD if self.acquisition.tracking_pid is not None else 0)

    def _emit_tracked(self, ahead: int, wait: bool = True) -> None:
        """Emit the pairs tracked, oldest first, until at most ``ahead`` are in flight (waiting for them unless
        ``wait`` is False: then only those tracked already)."""
        while self._pending and (len(self._pending) > ahead or self.acquisition.ready()):
            if not wait and not self.acquisition.ready():
                return
            frame, imu, reading, now = self._pending.popleft()
            self._emit(self.acquisition.finish(), frame, imu, reading, now)
            if self.acquisition.tracking_stops != self._tracking_said:
                self._tracking_said = self.acquisition.tracking_stops
                self.store_failed.emit(f"Tracking: {self.acquisition.tracking_problem}.")

    def _emit(self, outcome: FrameOutcome, frame, imu: ImuSnapshot, reading: ImuReading, now: int) -> None:
        overlay_left = overlay_right = None
        tracker = self.acquisition.tracker
        if outcome.fix is not None:
            drawn = np.array([outcome.fix.tip, outcome.fix.tip + _AXIS_DRAWN_MM * outcome.fix.axis])
            overlay_left, overlay_right = (DISPLAY_SCALE * tracker.project(drawn, eye) for eye in (0, 1))
        hot_spots = self._hot_spots(outcome, reading)
        self.frame_processed.emit(FrameResult(outcome, display_rgb(frame.left), display_rgb(frame.right),
                                              overlay_left, overlay_right, imu, frame.skew_ms, self._fps_measured, now,
                                              *hot_spots))

    @Slot(object)
    def set_navigation(self, state: NavigationState) -> None:
        """The latest registration's hot spots not found yet, found, its confidence and whether it is current
        (:class:`~snreg.workflow.navigation.NavigationState`): drawn on both feeds from the next frame."""
        self._navigation = state

    def _hot_spots(self, outcome: FrameOutcome, reading: ImuReading) -> tuple:
        """(left layer, right layer, guidance words) of the hot spots not found yet, seen from the camera's pose at
        this frame (the chain at its insertion and IMU orientation, as the tip is mapped)."""
        state = self._navigation
        views = []
        if state.targets:
            pose = trocar_from_camera_at(self.acquisition.chain, reading.earth_from_imu, outcome.insertion)
            views = navigate(list(state.targets), geometry.invert(pose), self.acquisition.tracker.project,
                             self.acquisition.tracker.calibration.image_size, outcome.tip_trocar)
        return (*(feed_layer(views, eye, state, DISPLAY_SCALE) for eye in (0, 1)), guidance_text(views, state))


def start_worker(worker: AcquisitionWorker) -> QThread:
    """Move ``worker`` to a new thread and start it; connect its signals first. Stop with :func:`stop_worker`."""
    thread = QThread()
    worker.moveToThread(thread)
    thread.started.connect(worker.start)
    thread.start()
    return thread


def stop_worker(worker: AcquisitionWorker, thread: QThread) -> None:
    """Stop the frame loop in the worker's thread, then end the thread and wait for it."""
    QMetaObject.invokeMethod(worker, "stop", Qt.ConnectionType.BlockingQueuedConnection)
    thread.quit()
    thread.wait()
