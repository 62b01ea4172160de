"""The hardware rig: the cameras, IMU port, calibration and probe model a technician chose, opened for acquisition.

Why: the app runs on a :class:`~snreg.rig.protocols.Rig`, the demo's or this one, so the code after the devices
is the same with hardware as in the demo. Everything a user can get wrong (no calibration file, a calibration
made at another image size, a serial port that does not exist) is a ``ValueError`` whose message is one sentence
saying what to do (:class:`~snreg.errors.SourceError` and :class:`~snreg.errors.CalibrationFileError` are
``ValueError`` too). The first frame pair a source delivers is checked against the calibration's image size
before acquisition starts.

Without an IMU (``serial_port`` None) ``imu`` is an :class:`AbsentImu`: an :class:`~snreg.rig.protocols.Imu` with
state ``"absent"``, a one-sentence problem that the screen's IMU line shows, a level orientation
(``earth_from_imu`` the identity) and no samples. Acquisition then runs unchanged and stores nodes in the trocar
frame of the chain's reference pose, which is right only while the endoscope does not move.

>>> config = RigConfig(mode="folder", left="rec/left_*.png", right="rec/right_*.png",
...                    calibration_path="calib.yaml", serial_port="/dev/ttyACM0")
>>> rig = HardwareRig(RigConfig.from_dict(config.to_dict()))
>>> source = rig.frame_source()          # in the worker thread
>>> rig.imu.snapshot().euler_deg, rig.fps
>>> rig.close()
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import numpy as np

from snreg.camera import StereoCalibration, load_calibration
from snreg.chain import ChainCalibration
from snreg.imu.monitor import ImuAt, ImuMonitor, ImuSnapshot
from snreg.probe import default_probe_model, load_probe_model
from snreg.rig.config import RigConfig
from snreg.sources import (FrameSource, ImageFolderSource, OpenCVPairSource, OpenCVStackedSource, SourceError,
                           SourceState, StereoFrame, VideoFilePairSource)

__all__ = ["HardwareRig", "AbsentImu", "ABSENT", "check_source", "open_frame_source"]

ABSENT = "absent"                 # the IMU state when no port was chosen
FIRST_FRAME_TIMEOUT_S = 5.0       # a camera that has not delivered a pair by then is reported


def _capture_device(text: str) -> int | str:
    """An OpenCV device: a camera index when the text is a number, else a device path or URL."""
    text = text.strip()
    return int(text) if text.isdigit() else text


def open_frame_source(config: RigConfig) -> FrameSource:
    """The configured frame source, opened but not read (SourceError says what is wrong)."""
    if config.mode == "pair":
        return OpenCVPairSource(_capture_device(config.left), _capture_device(config.right),
                                frame_size=config.frame_size)
    if config.mode == "stacked":
        return OpenCVStackedSource(_capture_device(config.device), config.layout, frame_size=config.frame_size)
    if config.mode == "video":
        return VideoFilePairSource(config.left.strip(), config.right.strip())
    return ImageFolderSource(config.left.strip(), config.right.strip(), fps=config.fps)


class _PrimedSource(FrameSource):
    """``inner`` whose first pair was already read (to check it): that pair comes first, then the rest of ``inner``."""

    def __init__(self, inner: FrameSource, first: StereoFrame):
        super().__init__(inner.name)
        self._inner, self._first = inner, first

    def _read(self) -> StereoFrame | None:
        if self._first is not None:
            frame, self._first = self._first, None
            return frame
        frame = self._inner.read()
        if frame is None and self._inner.state is not SourceState.OPEN:
            self._stop(self._inner.state, self._inner.problem)
        return frame

    def _release(self) -> None:
        self._inner.close()


def _first_frame(source: FrameSource, timeout_s: float) -> StereoFrame:
    """The first pair ``source`` delivers within ``timeout_s``; SourceError (source closed) when none comes."""
    deadline = time.monotonic() + timeout_s
    while source.state is SourceState.OPEN and time.monotonic() < deadline:
        frame = source.read()
        if frame is not None:
            return frame
    problem = source.problem or f"{source.name} delivered no frame pair within {timeout_s:g} s; check the devices."
    source.close()
    raise SourceError(problem)


def _frame_size(frame: StereoFrame) -> tuple[int, int]:
    """(width, height) of the left eye; SourceError if the eyes differ."""
    left, right = frame.left.shape[1::-1], frame.right.shape[1::-1]
    if left != right:
        raise SourceError(f"The left frames are {left[0]}x{left[1]} but the right ones {right[0]}x{right[1]}; "
                          "both cameras must deliver the same size.")
    return left


def _check_size(size: tuple[int, int], calibration: StereoCalibration, calibration_path: str) -> None:
    expected = tuple(calibration.image_size)
    if tuple(size) != expected:
        raise ValueError(f"The frames are {size[0]}x{size[1]} per eye but the calibration {calibration_path} is for "
                         f"{expected[0]}x{expected[1]}; choose the calibration made at this size or set the cameras "
                         f"to {expected[0]}x{expected[1]}.")


def _checked_source(config: RigConfig, calibration: StereoCalibration | None,
                    timeout_s: float) -> tuple[FrameSource, tuple[int, int]]:
    """The configured source with its first pair read and checked (against ``calibration`` if given), and its size."""
    source = open_frame_source(config)
    first = _first_frame(source, timeout_s)
    try:
        size = _frame_size(first)
        if calibration is not None:
            _check_size(size, calibration, config.calibration_path)
    except ValueError:
        source.close()
        raise
    return _PrimedSource(source, first), size


def check_source(config: RigConfig, *, timeout_s: float = FIRST_FRAME_TIMEOUT_S) -> tuple[int, int]:
    """Open the configured source, read one pair and close it: its (width, height) per eye.

    With a calibration file chosen, the size must be the calibration's. ValueError (one sentence) otherwise.
    Blocks up to ``timeout_s`` (longer while a camera opens): call it from a worker thread.
    """
    if config.source_missing:
        raise ValueError(config.source_missing)
    calibration = load_calibration(config.calibration_path) if config.calibration_path.strip() else None
    source, size = _checked_source(config, calibration, timeout_s)
    source.close()
    return size


class AbsentImu:
    """The IMU when there is none: state ``"absent"``, level orientation, no samples (see the module docstring)."""

    PROBLEM = ("no IMU port was chosen, so the endoscope is taken as held still in its reference pose; "
               "choose the IMU's port in the device dialog to follow its motion")

    def start(self) -> "AbsentImu":
        return self

    def stop(self) -> None:
        """Nothing to stop."""

    def take_samples(self) -> list:
        return []

    def snapshot(self) -> ImuSnapshot:
        return ImuSnapshot(ABSENT, self.PROBLEM, 0.0, 0.0, (0.0, 0.0, 0.0), np.eye(3), 0, 0)

    def orientation_at(self, t_host_ns: int) -> ImuAt:
        return ImuAt(np.eye(3), 0.0, ABSENT)


def _start_imu(config: RigConfig) -> ImuMonitor | AbsentImu:
    port = config.serial_port
    if port is None:
        return AbsentImu()
    if os.path.isabs(port) and not os.path.exists(port):
        raise ValueError(f"The IMU port {port} does not exist; plug the IMU in, or choose another port or none.")
    return ImuMonitor(port, baudrate=config.baudrate).start()


class HardwareRig:
    """The chosen devices opened as a :class:`~snreg.rig.protocols.Rig`: ``calibration``, ``probe``, ``chain``,
    ``imu`` (started), ``fps``, the sources.

    ``chain``: the session's calibrated chain, else the thesis's manual one. Raises ValueError (one
    sentence) when the choice is incomplete or a file or port cannot be used; nothing stays open then.
    """

    def __init__(self, config: RigConfig, chain: ChainCalibration | None = None):
        if config.missing:
            raise ValueError(config.missing)
        self.config = config
        self.calibration = load_calibration(config.calibration_path)
        if config.eye_size() is not None:
            _check_size(config.eye_size(), self.calibration, config.calibration_path)
        self.probe = load_probe_model(config.probe_path) if config.probe_path else default_probe_model()
        self.chain = chain if chain is not None else ChainCalibration.manual()
        self.fps = config.fps
        self.simulated = False
        self.moving_camera = True           # an endoscope in surgery slides in its trocar
        self.imu = _start_imu(config)

    def frame_source(self) -> FrameSource:
        """The cameras or files, opened, with the first pair checked against the calibration.

        Call it in the worker thread (opening a camera can take a second). ValueError (one sentence) when
        they cannot be used.
        """
        source, _ = _checked_source(self.config, self.calibration, FIRST_FRAME_TIMEOUT_S)
        return source

    def board_source(self) -> FrameSource:
        """The cameras for the stereo calibration wizard, not checked against the calibration being replaced (the
        cameras may run at a new resolution). Call it in the worker thread."""
        return open_frame_source(self.config)

    def pivot_source(self) -> tuple[Callable[[], FrameSource], ImuMonitor | AbsentImu]:
        """The trocar wizard's feed factory (the rig's cameras) and the IMU that goes with it (the rig's own)."""
        return self.frame_source, self.imu

    def tissue_source(self) -> tuple[Callable[[], FrameSource], ImuMonitor | AbsentImu]:
        """The same as :meth:`pivot_source`: the camera turns over tissue instead of a board."""
        return self.pivot_source()

    @property
    def description(self) -> str:
        """The devices in a few words, for the title bar and the status line."""
        cameras = self.config.device if self.config.mode == "stacked" else f"{self.config.left} / {self.config.right}"
        return f"{self.config.mode} {cameras}, IMU {self.config.serial_port or 'none'}"

    def close(self) -> None:
        """Stop the IMU; call after the worker has stopped (and closed the frame source)."""
        self.imu.stop()
