"""Acquisition: each stereo pair into a probe fix in the camera and trocar frames, the streams into the
session, and Store SN, undo and auto-store over the last valid fixes.

Why here and not in the GUI: the app's worker thread and ``snreg demo --headless`` must run the very same
steps (DESIGN.md §5: real and simulated devices share the code after the sources). A node is the median
of the last N valid tip fixes (thesis §5.2: N = 60) in both frames, with their spread.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from snreg.camera import StereoCalibration
from snreg.chain import ChainCalibration, camera_from_probe, camera_to_trocar, trocar_from_probe
from snreg.errors import StoreError
from snreg.imu.protocol import ImuSample
from snreg.probe import ProbeModel
from snreg.session import IntraopNode, Session
from snreg.sources import StereoFrame
from snreg.tracking import ProbeFix, StereoTracker, TrackingError, summarise

THESIS_FIXES_PER_NODE = 60
STILL_SPREAD_MM = 1.0           # the store window counts as "held still" below this spread (RMS about the median)
AUTO_STORE_SEPARATION_MM = 10.0  # auto-store only this far from every stored node: one node per rest


@dataclass(frozen=True, eq=False)
class FrameOutcome:
    """What one pair gave: the fix (None with the ``reason``), the tip in the trocar frame (mm), and the store
    window: how many valid fixes it holds (at most N), their spread (mm, NaN until full), whether that is still,
    and whether the auto-store rule (full, still, and over ``AUTO_STORE_SEPARATION_MM`` from every stored node) would store it now.
    ``trocar_from_probe`` (4, 4): the probe pose at the frame's IMU orientation (tip, axis backwards as z), None without
    a fix; the live link to 3D Slicer streams it."""

    index: int
    fix: ProbeFix | None
    reason: str
    tip_trocar: np.ndarray | None
    valid_fixes: int
    window_spread_mm: float
    still: bool
    auto_store_due: bool
    track_ms: float
    trocar_from_probe: np.ndarray | None = None


@dataclass(frozen=True)
class ImuReading:
    """The endoscope orientation at a frame: ``earth_from_imu`` (3, 3) and the raw samples since the last frame."""

    earth_from_imu: np.ndarray
    samples: Sequence[ImuSample] = ()


class Acquisition:
    """Tracks pairs, keeps the last ``fixes_per_node`` valid fixes, records streams and stores nodes in ``session``."""

    def __init__(self, calibration: StereoCalibration, probe: ProbeModel, chain: ChainCalibration, session: Session,
                 *, fixes_per_node: int = THESIS_FIXES_PER_NODE):
        self.tracker = StereoTracker(calibration, probe)
        self.chain, self.session = chain, session
        self.fixes_per_node = max(1, int(fixes_per_node))
        self._fixes: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=self.fixes_per_node)
        self._stored_here: list[str] = []          # ids stored through this object, for undo

    def set_fixes_per_node(self, n: int) -> None:
        """Store the median of the last ``n`` valid fixes (thesis: 60); keeps the fixes already collected."""
        self.fixes_per_node = max(1, int(n))
        self._fixes = deque(self._fixes, maxlen=self.fixes_per_node)

    def process(self, frame: StereoFrame, imu: ImuReading) -> FrameOutcome:
        """Track one pair at the given IMU orientation, record the frame, probe and IMU streams, update the window."""
        self._record_imu(imu.samples)
        self.session.append_frames(frame.t_left_ns, frame.t_right_ns, frame.index)
        started = time.perf_counter()
        fix, reason, tip_trocar, pose = None, "", None, None
        try:
            fix = self.tracker.track(frame.left, frame.right)
        except TrackingError as err:
            reason = str(err)
        track_ms = (time.perf_counter() - started) * 1e3
        if fix is not None:
            tip_trocar = camera_to_trocar(self.chain, imu.earth_from_imu, fix.tip)
            pose = trocar_from_probe(self.chain, imu.earth_from_imu, camera_from_probe(fix.tip, fix.axis))
            self._fixes.append((fix.tip, tip_trocar))
            self.session.append_probe(frame.t_left_ns, frame.t_right_ns, fix.tip, fix.centre, fix.axis, fix.quality)
        window = self._window_trocar()
        spread = window.spread_mm if window is not None else float("nan")
        still = bool(spread <= STILL_SPREAD_MM)
        return FrameOutcome(frame.index, fix, reason, tip_trocar, len(self._fixes), spread, still,
                            still and self._away_from_stored(window.xyz), track_ms, pose)

    def store(self, node_id: str, label: str, *, counts: float = float("nan"), left_jpeg=b"",
              right_jpeg=b"") -> IntraopNode:
        """The median of the store window as node ``node_id``, durable on return; :class:`StoreError` when the
        window is not full yet. Snapshots are JPEG bytes or BGR images."""
        if len(self._fixes) < self.fixes_per_node:
            raise StoreError(f"only {len(self._fixes)} of {self.fixes_per_node} valid fixes so far; "
                             "hold the probe on the node")
        camera = summarise(np.array([f[0] for f in self._fixes]))
        trocar = summarise(np.array([f[1] for f in self._fixes]))
        node = self.session.add_intraop_node(node_id, label, trocar.xyz, xyz_camera=camera.xyz,
                                             spread_mm=trocar.spread_mm, n_frames=trocar.n_frames, counts=counts,
                                             left_jpeg=left_jpeg, right_jpeg=right_jpeg)
        self._stored_here.append(node.id)
        return node

    def undo(self) -> IntraopNode:
        """Take back the node stored last (in this run, else the session's last); :class:`StoreError` if none."""
        stored = [n.id for n in self.session.intraop_records()]
        while self._stored_here and self._stored_here[-1] not in stored:
            self._stored_here.pop()
        target = self._stored_here.pop() if self._stored_here else (stored[-1] if stored else None)
        if target is None:
            raise StoreError("there is no stored node to undo")
        return self.session.remove_intraop_node(target)

    def _away_from_stored(self, here: np.ndarray) -> bool:
        """Auto-store rule, for a full and still window with median ``here``: away from every stored node."""
        stored = [node.xyz_trocar for node in self.session.intraop_records()]
        return not stored or float(np.min(np.linalg.norm(np.array(stored) - here, axis=1))) > AUTO_STORE_SEPARATION_MM

    def _window_trocar(self):
        """Median and spread of the full store window in the trocar frame (once per frame); None until full."""
        if len(self._fixes) < self.fixes_per_node:
            return None
        return summarise(np.array([f[1] for f in self._fixes]))

    def _record_imu(self, samples: Sequence[ImuSample]) -> None:
        if not samples:
            return
        self.session.append_imu(np.array([s.t_host_ns for s in samples], dtype=np.int64),
                                np.array([s.t_device_us for s in samples], dtype=np.int64) * 1000,
                                np.array([s.accel_g for s in samples]), np.array([s.gyro_dps for s in samples]))
