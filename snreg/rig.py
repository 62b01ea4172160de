"""The hardware rig: the cameras, IMU port, calibration and probe model a technician chose, opened for acquisition.

Why: the acquisition screen runs on a "rig" (calibration, probe model, chain, a started IMU monitor, a
frame-source factory), the same interface as :class:`snreg.demo.rig.DemoRig`, so the code after the
devices is the same with hardware as in the demo. :class:`RigConfig` is the choice itself, plain values
that a device dialog fills in and the app keeps between runs (``to_dict``/``from_dict``);
:class:`HardwareRig` opens it. Everything a user can get wrong (no calibration file, a calibration made
at another image size, a serial port that does not exist) is a ``ValueError`` whose message is one
sentence saying what to do (:class:`~snreg.sources.SourceError` and
:class:`~snreg.calibration.CalibrationFileError` are ``ValueError`` too).

Camera modes: ``pair`` (two devices, ``left``/``right``: an index such as ``"0"``, a device path or a
URL), ``stacked`` (one ``device`` carrying both eyes, ``layout`` side_by_side or top_bottom), ``video``
(``left``/``right`` video files) and ``folder`` (``left``/``right`` glob patterns of images).
``frame_size`` (width, height) is asked of each capture device (for ``stacked`` the whole frame holding
both eyes); None keeps the device's default. The first frame pair a source delivers is checked against
the calibration's image size before acquisition starts.

Without an IMU (``serial_port`` None) ``imu`` is an :class:`AbsentImu`: it answers like
:class:`~snreg.imu.monitor.ImuMonitor` with state ``"absent"``, a one-sentence problem that the screen's
IMU line shows, a level orientation (``earth_from_imu`` the identity) and no samples. Acquisition then
runs unchanged and stores nodes in the trocar frame of the chain's reference pose, which is right only
while the endoscope does not move.

>>> config = RigConfig(mode="folder", left="rec/left_*.png", right="rec/right_*.png",
...                    calibration_path="calib.yaml", serial_port="/dev/ttyACM0")
>>> rig = HardwareRig(RigConfig.from_dict(config.to_dict()))
>>> source = rig.frame_source()          # in the worker thread
>>> rig.imu.snapshot().euler_deg, rig.fps
>>> rig.close()
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass, fields

import numpy as np

from snreg.camera import StereoCalibration, load_calibration
from snreg.chain import ChainCalibration
from snreg.imu.monitor import ImuMonitor, ImuSnapshot
from snreg.imu.reader import DEFAULT_BAUD
from snreg.probe import default_probe_model, load_probe_model
from snreg.sources import (FrameSource, ImageFolderSource, OpenCVPairSource, OpenCVStackedSource, SourceError,
                           SourceState, StereoFrame, VideoFilePairSource)
from snreg.sources.capture import LAYOUTS

__all__ = ["RigConfig", "HardwareRig", "AbsentImu", "CAMERA_MODES", "ABSENT", "check_source", "open_frame_source"]

CAMERA_MODES = ("pair", "stacked", "video", "folder")
ABSENT = "absent"                 # the IMU state when no port was chosen
FIRST_FRAME_TIMEOUT_S = 5.0       # a camera that has not delivered a pair by then is reported


@dataclass(frozen=True)
class RigConfig:
    """The devices and files of a rig; see the module docstring for the camera modes. Checked on creation."""

    mode: str = "pair"
    left: str = ""
    right: str = ""
    device: str = ""
    layout: str = "side_by_side"
    frame_size: tuple[int, int] | None = None
    fps: float = 30.0
    serial_port: str | None = None
    baudrate: int = DEFAULT_BAUD
    calibration_path: str = ""
    probe_path: str | None = None

    def __post_init__(self):
        if self.mode not in CAMERA_MODES:
            raise ValueError(f"Unknown camera mode {self.mode!r}; use one of {', '.join(CAMERA_MODES)}.")
        if self.layout not in LAYOUTS:
            raise ValueError(f"Unknown stereo layout {self.layout!r}; use one of {', '.join(LAYOUTS)}.")
        for name in ("left", "right", "device", "calibration_path"):
            if not isinstance(getattr(self, name), str):
                raise ValueError(f"The rig's {name} must be text, not {getattr(self, name)!r}.")
        for name in ("serial_port", "probe_path"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, str):
                raise ValueError(f"The rig's {name} must be text or None, not {value!r}.")
            object.__setattr__(self, name, value or None)
        object.__setattr__(self, "fps", _positive(self.fps, "frame rate (fps)", float))
        object.__setattr__(self, "baudrate", _positive(self.baudrate, "baud rate", int))
        if self.frame_size is not None:
            if not isinstance(self.frame_size, (tuple, list)) or len(self.frame_size) != 2:
                raise ValueError(f"The frame size must be a width and a height, not {self.frame_size!r}.")
            size = tuple(_positive(v, "frame width and height", int) for v in self.frame_size)
            object.__setattr__(self, "frame_size", size)

    @property
    def source_missing(self) -> str:
        """What the camera choice still lacks, in one sentence; empty when the frame source can be opened."""
        if self.mode == "stacked":
            return "" if self.device.strip() else "Choose the camera that delivers both eyes."
        named = {"pair": ("left camera", "right camera"), "video": ("left video file", "right video file"),
                 "folder": ("left image pattern", "right image pattern")}[self.mode]
        lacking = [what for what, value in zip(named, (self.left, self.right)) if not value.strip()]
        if lacking:
            return f"Choose the {' and the '.join(lacking)}."
        if self.mode == "pair" and self.left.strip() == self.right.strip():
            return "The left and right cameras are the same device; choose two different ones."
        return ""

    @property
    def missing(self) -> str:
        """What the whole choice still lacks (cameras, then calibration), in one sentence; empty when complete."""
        if self.source_missing:
            return self.source_missing
        if not self.calibration_path.strip():
            return "Choose the stereo calibration file (from the calibration wizard or 'snreg calibrate stereo')."
        return ""

    def eye_size(self) -> tuple[int, int] | None:
        """The (width, height) of each eye that ``frame_size`` gives, None when the frames decide it."""
        if self.frame_size is None or self.mode not in ("pair", "stacked"):
            return None
        width, height = self.frame_size
        if self.mode == "pair":
            return width, height
        return (width // 2, height) if self.layout == "side_by_side" else (width, height // 2)

    def to_dict(self) -> dict:
        """Plain values (text, numbers, a list, None) for QSettings or JSON; :meth:`from_dict` reads it back."""
        data = asdict(self)
        data["frame_size"] = list(self.frame_size) if self.frame_size is not None else None
        return data

    @classmethod
    def from_dict(cls, data) -> "RigConfig":
        """A config from :meth:`to_dict`'s values (missing keys take their defaults); ValueError says what is wrong."""
        if not isinstance(data, dict):
            raise ValueError(f"The stored device choice is not a table of settings ({type(data).__name__}); "
                             "choose the devices again.")
        unknown = sorted(set(data) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"The stored device choice has unknown settings ({', '.join(map(str, unknown))}); "
                             "choose the devices again.")
        return cls(**data)


def _positive(value, what: str, kind: type):
    """``value`` as ``kind`` if it is a finite positive number (numbers given as text are accepted)."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if isinstance(value, bool) or not (math.isfinite(number) and number > 0) or (kind is int and number != int(number)):
        raise ValueError(f"The {what} must be a positive {'whole ' if kind is int else ''}number, not {value!r}.")
    return kind(number)


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


def _start_imu(config: RigConfig) -> ImuMonitor | AbsentImu:
    port = config.serial_port
    if port is None:
        return AbsentImu()
    if os.path.isabs(port) and not os.path.exists(port):
        raise ValueError(f"The IMU port {port} does not exist; plug the IMU in, or choose another port or none.")
    return ImuMonitor(port, baudrate=config.baudrate).start()


class HardwareRig:
    """The chosen devices opened: ``calibration``, ``probe``, ``chain``, ``imu`` (started), ``fps``, :meth:`frame_source`.

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
        self.imu = _start_imu(config)

    def frame_source(self) -> FrameSource:
        """The cameras or files, opened, with the first pair checked against the calibration.

        Call it in the worker thread (opening a camera can take a second). ValueError (one sentence) when
        they cannot be used.
        """
        source, _ = _checked_source(self.config, self.calibration, FIRST_FRAME_TIMEOUT_S)
        return source

    def close(self) -> None:
        """Stop the IMU; call after the worker has stopped (and closed the frame source)."""
        self.imu.stop()
