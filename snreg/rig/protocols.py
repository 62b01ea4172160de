"""What the app and the workflow need of a rig and of its IMU: the demo's and the hardware's both answer this.

Why: the code after the devices is one code path (docs/design.md, Habits). The acquisition worker, the calibration
wizards and the device dialog use only what is named here, so nothing above asks which rig it runs on; a new
rig (another endoscope, a replayed recording) only has to satisfy these protocols.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

from snreg.camera import StereoCalibration
from snreg.chain import ChainCalibration
from snreg.imu.monitor import ImuAt, ImuSnapshot
from snreg.imu.protocol import ImuSample
from snreg.probe import ProbeModel
from snreg.sources import FrameSource

__all__ = ["Imu", "Rig"]


@runtime_checkable
class Imu(Protocol):
    """The endoscope's orientation and its raw samples: :class:`~snreg.imu.monitor.ImuMonitor` on a serial port,
    :class:`~snreg.rig.hardware.AbsentImu` without one, simulated ones in :mod:`snreg.demo`."""

    def start(self) -> "Imu":
        """Begin reading (idempotent where the device allows it); returns itself."""

    def stop(self) -> None:
        """Stop reading and release the device."""

    def snapshot(self) -> ImuSnapshot:
        """The state and orientation now (thread-safe)."""

    def take_samples(self) -> list[ImuSample]:
        """The raw samples received since the last call, for recording (an empty list when there are none)."""

    def orientation_at(self, t_host_ns: int) -> ImuAt:
        """The orientation at a host time (a frame's grab time, ``time.perf_counter_ns``), with how far the nearest
        sample is from it (thread-safe)."""


@runtime_checkable
class Rig(Protocol):
    """The devices of one set-up.

    ``calibration`` is what tracking uses (a stereo calibration wizard replaces it), ``probe`` the probe model,
    ``chain`` the transform chain (the trocar wizard replaces it), ``imu`` the started endoscope IMU, ``fps`` the
    nominal frame rate; ``moving_camera``: the camera slides in the trocar, so acquisition follows its insertion
    (issue 27) unless the operator turned that off; ``simulated`` and ``description`` say what the rig is, for display
    only.
    """

    calibration: StereoCalibration
    probe: ProbeModel
    chain: ChainCalibration
    imu: Imu
    fps: float
    moving_camera: bool
    simulated: bool

    @property
    def description(self) -> str:
        """The devices in a few words, for the title bar and the status line."""

    def frame_source(self) -> FrameSource:
        """The stereo feed for acquisition, opened (call it in the worker thread: opening can take seconds)."""

    def board_source(self) -> FrameSource:
        """The stereo feed for the checkerboard calibration wizard (call it in the worker thread)."""

    def pivot_source(self) -> tuple[Callable[[], FrameSource], Imu]:
        """The trocar wizard's feed factory (called in its capture thread) and the IMU whose orientation belongs to
        the frames it delivers."""

    def tissue_source(self) -> tuple[Callable[[], FrameSource], Imu]:
        """As :meth:`pivot_source`, for the trocar wizard's turn over tissue (the same cameras and IMU on a real rig)."""

    def close(self) -> None:
        """Release every device; call after the workers have stopped."""
