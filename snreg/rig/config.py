"""The devices and files a technician chose for a rig: plain values, checked on creation, kept between runs.

Camera modes: ``pair`` (two devices, ``left``/``right``: an index such as ``"0"``, a device path or a URL),
``stacked`` (one ``device`` carrying both eyes, ``layout`` side_by_side or top_bottom), ``video`` (``left``/``right``
video files), ``folder`` (``left``/``right`` glob patterns of images) and ``replay`` (``left``: a session recorded with
video, played back ``speed`` times faster with its own IMU stream and calibration; :class:`snreg.demo.replay.ReplayRig`). ``frame_size`` (width, height) is asked
of each capture device (for ``stacked`` the whole frame holding both eyes); None keeps the device's default.
A device dialog fills a :class:`RigConfig` in and the app keeps it (``to_dict``/``from_dict``);
:class:`~snreg.rig.hardware.HardwareRig` opens it.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

from snreg.imu.reader import DEFAULT_BAUD
from snreg.sources.capture import LAYOUTS

__all__ = ["RigConfig", "CAMERA_MODES"]

CAMERA_MODES = ("pair", "stacked", "video", "folder", "replay")


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
    speed: float = 1.0

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
        object.__setattr__(self, "speed", _positive(self.speed, "replay speed", float))
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
        if self.mode == "replay":
            return "" if self.left.strip() else "Choose the recorded session (.h5) to replay."
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
        if not self.calibration_path.strip() and self.mode != "replay":     # a replay tracks with its session's
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
