"""The acquisition worker: reads frame pairs, tracks the probe, maps it to the trocar frame, stores nodes.

Why: capture, tracking and session writes must never run on the GUI thread (DESIGN.md §5). The worker
lives in its own QThread, paced by a timer there; every frame ends as one :class:`FrameResult` signal,
and "Store SN" requests arrive as queued slot calls between frames, so a node is the median of fixes
this worker itself kept. Connect the signals before :func:`start_worker`.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from PySide6.QtCore import QCoreApplication, QMetaObject, QObject, Qt, QThread, QTimer, Signal, Slot

from snreg.calibration.files import StereoCalibration
from snreg.chain import ChainCalibration, camera_to_trocar
from snreg.session import Session, SessionError
from snreg.sources import FrameSource
from snreg.tracking import ProbeFix, StereoTracker, TrackingError, summarise
from snreg.imu.monitor import ImuMonitor, ImuSnapshot

THESIS_FIXES_PER_NODE = 60
DISPLAY_SCALE = 0.5          # feeds are shown at this fraction of the camera resolution: less work on the GUI thread
_AXIS_DRAWN_MM = 50.0


@dataclass(frozen=True, eq=False)
class FrameResult:
    """One processed pair: RGB images for display, the fix (or why there is none) and where to draw it.

    Images and overlays are at ``DISPLAY_SCALE`` of the camera resolution.
    ``overlay_left``/``overlay_right``: (2, 2) display pixels of the tip and of a point ``_AXIS_DRAWN_MM`` up the
    axis, None without a fix. ``valid_fixes``: fixes now in the store window (at most N).
    """

    index: int
    left_rgb: np.ndarray
    right_rgb: np.ndarray
    fix: ProbeFix | None
    reason: str
    overlay_left: np.ndarray | None
    overlay_right: np.ndarray | None
    tip_trocar: np.ndarray | None
    imu: ImuSnapshot
    skew_ms: float
    fps: float
    track_ms: float
    valid_fixes: int
    t_host_ns: int


@dataclass(frozen=True)
class StoreRequest:
    node_id: str
    label: str
    n_fixes: int
    counts: float = float("nan")


def _display_rgb(bgr: np.ndarray) -> np.ndarray:
    """The frame as the feeds show it: RGB at ``DISPLAY_SCALE``."""
    small = cv2.resize(bgr, None, fx=DISPLAY_SCALE, fy=DISPLAY_SCALE, interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_BGR2RGB)


class AcquisitionWorker(QObject):
    """Frame loop and node store. ``make_source`` runs in the worker thread (a renderer may take time to build)."""

    frame_processed = Signal(object)     # FrameResult
    node_stored = Signal(object)         # snreg.session.IntraopNode
    store_failed = Signal(str)           # one sentence saying what to do
    source_stopped = Signal(str)         # the source's problem

    def __init__(self, make_source: Callable[[], FrameSource], calibration: StereoCalibration, probe,
                 chain: ChainCalibration, imu: ImuMonitor, session: Session, fps: float,
                 max_fixes: int = THESIS_FIXES_PER_NODE):
        super().__init__()
        self._make_source, self._calibration, self._probe = make_source, calibration, probe
        self._chain, self._imu, self._session, self._fps = chain, imu, session, fps
        self._fixes: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=max_fixes)
        self._source: FrameSource | None = None
        self._tracker: StereoTracker | None = None
        self._timer: QTimer | None = None
        self._last_frame = None
        self._last_ns: int | None = None
        self._fps_measured = 0.0

    @Slot()
    def start(self) -> None:
        self._source = self._make_source()
        self._tracker = StereoTracker(self._calibration, self._probe)
        self._timer = QTimer(self)
        self._timer.setTimerType(Qt.TimerType.PreciseTimer)
        self._timer.timeout.connect(self._step)
        self._timer.start(round(1000 / self._fps))

    @Slot()
    def stop(self) -> None:
        """Stop the frame loop and hand this object back to the GUI thread, which deletes it later."""
        if self._timer is not None:
            self._timer.stop()
        if self._source is not None:
            self._source.close()
        self.moveToThread(QCoreApplication.instance().thread())

    @Slot(int)
    def set_max_fixes(self, n: int) -> None:
        """Keep the last ``n`` valid fixes for "Store SN" (thesis: 60)."""
        self._fixes = deque(self._fixes, maxlen=max(1, int(n)))

    @Slot(object)
    def store_node(self, request: StoreRequest) -> None:
        """Median and spread of the last ``request.n_fixes`` valid fixes into the session (durable on return)."""
        fixes = list(self._fixes)[-request.n_fixes:]
        if len(fixes) < request.n_fixes:
            self.store_failed.emit(f"Only {len(fixes)} of {request.n_fixes} valid fixes so far; hold the probe on the node.")
            return
        camera, trocar = summarise(np.array([f[0] for f in fixes])), summarise(np.array([f[1] for f in fixes]))
        left, right = (self._last_frame.left, self._last_frame.right) if self._last_frame is not None else (b"", b"")
        try:
            node = self._session.add_intraop_node(request.node_id, request.label, trocar.xyz, xyz_camera=camera.xyz,
                                                  spread_mm=trocar.spread_mm, n_frames=trocar.n_frames,
                                                  counts=request.counts, left_jpeg=left, right_jpeg=right)
        except (SessionError, OSError, ValueError) as err:
            self.store_failed.emit(f"The node was not stored: {err}")
            return
        self.node_stored.emit(node)

    @Slot()
    def _step(self) -> None:
        frame = self._source.read()
        if frame is None:
            self._timer.stop()
            self.source_stopped.emit(self._source.problem)
            return
        now = time.perf_counter_ns()
        if self._last_ns is not None:
            instant = 1e9 / max(now - self._last_ns, 1)
            self._fps_measured = instant if self._fps_measured == 0 else 0.9 * self._fps_measured + 0.1 * instant
        self._last_ns, self._last_frame = now, frame
        imu = self._imu.snapshot()
        started = time.perf_counter()
        fix, reason = None, ""
        try:
            fix = self._tracker.track(frame.left, frame.right)
        except TrackingError as err:
            reason = str(err)
        track_ms = (time.perf_counter() - started) * 1e3
        overlay_left = overlay_right = tip_trocar = None
        if fix is not None:
            tip_trocar = camera_to_trocar(self._chain, imu.earth_from_imu, fix.tip)
            self._fixes.append((fix.tip, tip_trocar))
            drawn = np.array([fix.tip, fix.tip + _AXIS_DRAWN_MM * fix.axis])
            overlay_left, overlay_right = (DISPLAY_SCALE * self._tracker.project(drawn, eye) for eye in (0, 1))
        self.frame_processed.emit(FrameResult(
            frame.index, _display_rgb(frame.left), _display_rgb(frame.right), fix, reason, overlay_left, overlay_right,
            tip_trocar, imu, frame.skew_ms, self._fps_measured, track_ms, len(self._fixes), now))


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
