"""Replaying a recorded session as a rig: its video as the cameras, its IMU stream on a pseudo-terminal.

Why: a technician trains on a real session and a developer reproduces what happened in the operating room, both on
the code a live session runs (docs/design.md, Habits). The frames come from :class:`~snreg.session.playback.RecordedFeed` (a
frame source, paced as recorded or ``speed`` times faster); the IMU samples go out as protocol lines on a
:class:`~snreg.demo.imu_simulator.SimulatedPort` with their recorded device clock, read back by the same
:class:`~snreg.imu.monitor.ImuMonitor` (serial reader and fusion) as a real IMU, both counted from one recorded
origin and started at one host time, so each frame meets the orientation it met when recorded. Calibration and chain
are the session's. A session recorded without an IMU replays with an absent one.

The camera's insertion is tracked in the replay when the recorded session tracked it live (the rule re-tracking's
"auto" follows, :func:`~snreg.workflow.retrack.insertion_tracked_live`): a surgery session's endoscope slid in its
trocar, and its nodes are mapped where the replayed video shows the camera, as live. Like the live acquisition's, the
tracker starts at the session chain's distance (the live run's start is on record: the first tracked
``streams/camera`` row, and in the app's sessions the ``acquisition_started`` event's "tracked, from ... mm"; it is
elsewhere only when the live tracker went on from an earlier run's insertion, "resumed at", or the chain was
calibrated again since). A session recorded without tracking replays at the chain's constant, as it was recorded.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from snreg.chain import ChainCalibration
from snreg.demo.imu_simulator import Faults, Readings, SimulatedPort, _LineSource
from snreg.errors import SourceError
from snreg.imu.monitor import ImuMonitor
from snreg.imu.protocol import DEVICE_CLOCK_WRAP_US
from snreg.odometry import InsertionTracker
from snreg.probe import default_probe_model
from snreg.rig.hardware import AbsentImu
from snreg.session import Session, SessionError
from snreg.session.playback import RecordedFeed, recorded_origin_ns
from snreg.session.reader import readable_rows
from snreg.sources import FrameSource
from snreg.workflow.acquisition import Acquisition, ImuReading
from snreg.workflow.retrack import insertion_tracked_live

_PORT_START_TIMEOUT_S = 10.0


class RecordedImu(_LineSource):
    """A session's ``streams/imu`` rows as protocol lines, due at their host time from ``origin_ns``."""

    sensor_name = "replay"
    decimals = 6

    def __init__(self, rows: np.ndarray, origin_ns: int):
        super().__init__(Faults(), seed=0)
        t_s = (np.asarray(rows["t_host_ns"], dtype=np.int64) - origin_ns) / 1e9
        steps = np.diff(t_s)
        self.rate_hz = float(1.0 / np.median(steps)) if len(steps) and np.median(steps) > 0 else 208.0
        self.readings = Readings(t_s, (np.asarray(rows["t_device_ns"], dtype=np.int64) // 1000) % DEVICE_CLOCK_WRAP_US,
                                 np.asarray(rows["acc_g"], dtype=float), np.asarray(rows["gyro_dps"], dtype=float))

    def _blocks(self, motion_offset_s: float = 0.0) -> Iterator[Readings]:
        yield self.readings


class ReplayRig:
    """A :class:`~snreg.rig.protocols.Rig` that plays a recorded session back ``speed`` times faster than recorded.

    ``moving_camera``: the recorded session tracked the camera's insertion live, so the replay tracks it too (module
    docstring).
    SessionError (one sentence) when the session cannot be replayed: unreadable, no video, no stereo calibration.
    """

    simulated = True

    def __init__(self, path: str | Path, *, speed: float = 1.0):
        self.path, self.speed = Path(path), float(speed)
        if not self.speed > 0:
            raise SessionError(f"the replay speed must be a positive number, not {speed!r}")
        with Session.open(self.path) as session:
            calibration, segments = session.calibration(), session.videos()
            imu = session.stream("imu")
            rows = readable_rows(imu) if hasattr(imu, "id") else np.asarray(imu)
            self.moving_camera = insertion_tracked_live(session)
        if not segments:
            raise SessionError(f"{self.path} has no recorded video to replay; choose a session recorded with video")
        if "stereo" not in calibration:
            raise SessionError(f"{self.path} holds no stereo calibration to track its video with")
        self.calibration, self.probe = calibration["stereo"], default_probe_model()
        self.chain = calibration.get("chain", ChainCalibration.manual())
        self.fps = segments[0].fps
        self.origin_ns = recorded_origin_ns(self.path)
        self._folder = tempfile.TemporaryDirectory(prefix="snreg-replay-imu-")
        self._port = None
        if len(rows) > 1:
            self._port = SimulatedPort(RecordedImu(rows, self.origin_ns), port_link=str(Path(self._folder.name) / "imu"),
                                       speed=self.speed).start()
            self.imu = ImuMonitor(self._port.port, device_rate=self.speed)    # its device clock runs at speed
        else:
            self.imu = AbsentImu()

    @property
    def description(self) -> str:
        return f"replay of {self.path.name} ({self.speed:g}x)"

    def frame_source(self, *, live: bool = True) -> FrameSource:
        """The recorded feed, started at the IMU replay's time 0 (call it in the worker thread); ``live``: frames
        skipped when the consumer falls behind, as a camera's; else every frame (:class:`RecordedFeed`)."""
        start_ns = None
        if self._port is not None:
            if not getattr(self.imu, "started", True):
                self.imu.start()
            deadline = time.monotonic() + _PORT_START_TIMEOUT_S
            while self._port.started_ns is None and time.monotonic() < deadline:
                time.sleep(0.005)
            start_ns = self._port.started_ns
        return RecordedFeed(self.path, speed=self.speed, origin_ns=self.origin_ns, start_ns=start_ns, live=live)

    def board_source(self) -> FrameSource:
        raise SourceError("A replay has no checkerboard recording; choose cameras (Devices) to calibrate.")

    def pivot_source(self):
        raise SourceError("A replay has no pivot recording; choose cameras and an IMU (Devices) to calibrate.")

    def tissue_source(self):
        return self.pivot_source()

    def close(self) -> None:
        self.imu.stop()
        if self._port is not None:
            self._port.stop()
        self._folder.cleanup()


def replay_headless(path: str | Path, out: str | Path, *, speed: float = 1.0, fixes_per_node: int = 60,
                    case_id: str = "replay", live: bool = False) -> list:
    """Replay ``path`` into a new session ``out`` with auto-store, as the app does with its box ticked (no window);
    every recorded frame unless ``live`` (then a slow machine skips frames as the app does); the camera's insertion
    tracked when the rig's camera moves (:attr:`ReplayRig.moving_camera`), from the chain's distance as the app's
    acquisition does. Returns the stored nodes (:class:`~snreg.session.IntraopNode`)."""
    rig = ReplayRig(path, speed=speed)
    try:
        with Session.create(out, case_id=case_id) as session:
            session.set_calibration(stereo=rig.calibration, chain=rig.chain)
            insertion = InsertionTracker(rig.calibration, rig.chain, probe=rig.probe) if rig.moving_camera else None
            acquisition = Acquisition(rig.calibration, rig.probe, rig.chain, session, fixes_per_node=fixes_per_node,
                                      imu_required=not isinstance(rig.imu, AbsentImu), video_fps=rig.fps,
                                      insertion=insertion)
            with rig.frame_source(live=live) as source:
                for frame in source:
                    outcome = acquisition.process(frame, ImuReading.at_frame(rig.imu, frame))
                    if outcome.auto_store_due:
                        acquisition.store(session.next_node_id(), "", left_jpeg=frame.left, right_jpeg=frame.right,
                                          trigger="auto")
            return session.intraop_records()
    finally:
        rig.close()
