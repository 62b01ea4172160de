"""Which cameras and serial ports are present: the choices a device dialog offers.

Why: a technician picks the endoscope's cameras and the IMU's port from a list, not by guessing
``/dev/video2`` or ``COM5``. On Linux the cameras are the ``/dev/video*`` nodes, named from
``/sys/class/video4linux/<node>/name`` (no device is opened, so listing is instant and disturbs no
running capture); nodes whose sysfs ``index`` is above 0 are skipped, because a UVC camera adds a
second node for its metadata that delivers no images. Elsewhere OpenCV opens indices ``0..max_index-1``
in turn, which takes up to a second per index: call it from a worker thread.

Serial ports come from pyserial's ``comports()``. A pseudo-terminal, such as the link that
``snreg imu simulate --port-link PATH`` makes, is not in that list: pass such paths as ``extra``.

>>> [camera.text for camera in list_cameras()]
['/dev/video0 - Integrated Camera']
>>> [port.text for port in list_serial_ports(extra=["/tmp/imu"])]
['/dev/ttyACM0 - Arduino Nano Every', '/tmp/imu - not listed by the system (a link to /dev/pts/3)']
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import cv2
from serial.tools.list_ports import comports

__all__ = ["CameraDevice", "SerialPortInfo", "list_cameras", "list_serial_ports"]

DEV_DIR = Path("/dev")
V4L_SYS_DIR = Path("/sys/class/video4linux")
PROBED_INDICES = 4


@dataclass(frozen=True)
class CameraDevice:
    """A video capture device: ``device`` is what OpenCV opens (an index, or a device path), ``name`` what it is."""

    device: int | str
    name: str

    @property
    def text(self) -> str:
        """One line for a list: the device and its name."""
        label = f"camera {self.device}" if isinstance(self.device, int) else self.device
        return f"{label} - {self.name}" if self.name else label


@dataclass(frozen=True)
class SerialPortInfo:
    """A serial port: ``device`` is what pyserial opens (``/dev/ttyACM0``, ``COM3``), ``description`` what it is."""

    device: str
    description: str

    @property
    def text(self) -> str:
        return f"{self.device} - {self.description}" if self.description else self.device


def _natural_key(text: str) -> list:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", text)]


def _read_text(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8", errors="replace").strip()
    except OSError:
        return None


def _v4l_cameras(dev_dir: Path, sys_dir: Path) -> list[CameraDevice]:
    """The ``video*`` nodes of ``dev_dir`` with their sysfs names, metadata nodes (sysfs index > 0) left out."""
    cameras = []
    for node in sorted(dev_dir.glob("video*"), key=lambda p: _natural_key(p.name)):
        if not re.fullmatch(r"video\d+", node.name):
            continue
        index = _read_text(sys_dir / node.name / "index")
        if index is not None and index.isdigit() and int(index) > 0:
            continue
        cameras.append(CameraDevice(str(node), _read_text(sys_dir / node.name / "name") or ""))
    return cameras


def _probed_cameras(max_index: int) -> list[CameraDevice]:
    """The indices below ``max_index`` that OpenCV can open (each opened and released at once)."""
    cameras = []
    for index in range(max_index):
        capture = cv2.VideoCapture(index)
        try:
            if capture.isOpened():
                backend = capture.getBackendName()
                cameras.append(CameraDevice(index, f"via {backend}" if backend else ""))
        finally:
            capture.release()
    return cameras


def list_cameras(*, max_index: int = PROBED_INDICES, dev_dir: Path = DEV_DIR,
                 sys_dir: Path = V4L_SYS_DIR) -> list[CameraDevice]:
    """The video capture devices present, in device order.

    Linux: the ``dev_dir/video*`` nodes, named from ``sys_dir`` (see the module docstring), none opened.
    Other systems: the OpenCV indices below ``max_index`` that open (slow: run it in a worker).
    """
    if sys.platform.startswith("linux"):
        return _v4l_cameras(Path(dev_dir), Path(sys_dir))
    return _probed_cameras(max_index)


def _extra_description(path: str) -> str:
    if os.path.islink(path):
        return f"not listed by the system (a link to {os.path.realpath(path)})"
    return "not listed by the system"


def list_serial_ports(extra: Iterable[str] = ()) -> list[SerialPortInfo]:
    """The serial ports pyserial finds, in name order, then each path of ``extra`` that exists and is not listed yet.

    ``extra``: ports the system does not list, such as a simulator's pseudo-terminal link; paths that do
    not exist are left out (the IMU simulator is not running, or the link was removed).
    """
    ports = sorted((SerialPortInfo(p.device, "" if p.description in ("n/a", p.device) else p.description)
                    for p in comports()), key=lambda p: _natural_key(p.device))
    listed = {port.device for port in ports}
    for path in extra:
        path = str(path)
        if path and path not in listed and os.path.exists(path):
            ports.append(SerialPortInfo(path, _extra_description(path)))
            listed.add(path)
    return ports
