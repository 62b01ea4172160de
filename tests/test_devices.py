"""Camera and serial-port listing on fake /dev and sysfs trees, a fake OpenCV and a fake comports()."""

import os
import types

from snreg.sources import devices
from snreg.sources.devices import CameraDevice, SerialPortInfo, list_cameras, list_serial_ports


def make_v4l_tree(tmp_path, nodes):
    """``nodes``: {node name: (sysfs name or None, sysfs index or None)}; returns (dev dir, sys dir)."""
    dev, sys_dir = tmp_path / "dev", tmp_path / "sys"
    dev.mkdir()
    sys_dir.mkdir()
    for node, (name, index) in nodes.items():
        (dev / node).touch()
        if name is not None or index is not None:
            (sys_dir / node).mkdir()
        if name is not None:
            (sys_dir / node / "name").write_text(name + "\n")
        if index is not None:
            (sys_dir / node / "index").write_text(f"{index}\n")
    return dev, sys_dir


def test_linux_lists_video_nodes_in_order_with_their_names_and_skips_metadata_nodes(tmp_path, monkeypatch):
    monkeypatch.setattr(devices.sys, "platform", "linux")
    dev, sys_dir = make_v4l_tree(tmp_path, {
        "video0": ("Firefly left", 0), "video1": ("Firefly left", 1),      # UVC metadata node: no images
        "video10": ("USB capture", 0), "video2": ("Firefly right", 0),
        "video3": (None, None),                                             # sysfs not readable: listed, unnamed
        "videoloop": ("not a node", 0), "ttyACM0": (None, None)})
    cameras = list_cameras(dev_dir=dev, sys_dir=sys_dir)
    assert cameras == [CameraDevice(str(dev / "video0"), "Firefly left"),
                       CameraDevice(str(dev / "video2"), "Firefly right"),
                       CameraDevice(str(dev / "video3"), ""), CameraDevice(str(dev / "video10"), "USB capture")]
    assert cameras[0].text == f"{dev / 'video0'} - Firefly left" and cameras[2].text == str(dev / "video3")


def test_linux_without_cameras_lists_none(tmp_path, monkeypatch):
    monkeypatch.setattr(devices.sys, "platform", "linux")
    assert list_cameras(dev_dir=tmp_path / "none", sys_dir=tmp_path / "none") == []


def test_elsewhere_probes_indices_with_opencv_and_releases_each(monkeypatch):
    monkeypatch.setattr(devices.sys, "platform", "win32")
    opened, released = [], []

    class FakeCapture:
        def __init__(self, index):
            self.index = index
            opened.append(index)

        def isOpened(self):
            return self.index in (0, 2)

        def getBackendName(self):
            return "MSMF"

        def release(self):
            released.append(self.index)

    monkeypatch.setattr(devices.cv2, "VideoCapture", FakeCapture)
    cameras = list_cameras(max_index=4)
    assert cameras == [CameraDevice(0, "via MSMF"), CameraDevice(2, "via MSMF")]
    assert cameras[1].text == "camera 2 - via MSMF"
    assert opened == released == [0, 1, 2, 3]


def fake_comports(monkeypatch, ports):
    monkeypatch.setattr(devices, "comports",
                        lambda: [types.SimpleNamespace(device=d, description=t) for d, t in ports])


def test_serial_ports_come_sorted_with_descriptions_and_placeholders_dropped(monkeypatch):
    fake_comports(monkeypatch, [("/dev/ttyS10", "n/a"), ("/dev/ttyACM0", "Arduino Nano Every"), ("/dev/ttyS2", "n/a")])
    ports = list_serial_ports()
    assert ports == [SerialPortInfo("/dev/ttyACM0", "Arduino Nano Every"), SerialPortInfo("/dev/ttyS2", ""),
                     SerialPortInfo("/dev/ttyS10", "")]
    assert [p.text for p in ports] == ["/dev/ttyACM0 - Arduino Nano Every", "/dev/ttyS2", "/dev/ttyS10"]


def test_extra_paths_add_a_pty_link_once_and_leave_out_missing_ones(tmp_path, monkeypatch):
    fake_comports(monkeypatch, [("/dev/ttyACM0", "Arduino Nano Every")])
    master, slave = os.openpty()                   # what 'snreg imu simulate --port-link' links to
    try:
        link = tmp_path / "imu"
        link.symlink_to(os.ttyname(slave))
        ports = list_serial_ports(extra=[str(link), str(link), "/dev/ttyACM0", str(tmp_path / "gone"), ""])
        assert [p.device for p in ports] == ["/dev/ttyACM0", str(link)]
        assert ports[1].description == f"not listed by the system (a link to {os.ttyname(slave)})"
    finally:
        os.close(master)
        os.close(slave)
