"""The device dialog driven offscreen: device lists (faked), folder mode, Test in a worker, OK only when complete."""

import cv2
import numpy as np
import pytest
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QDialog, QFileDialog

from snreg.camera import save_calibration, thesis_calibration
from snreg.rig import RigConfig
from snreg.sources.devices import CameraDevice, SerialPortInfo
from snreg_gui.wizards import device_dialog
from snreg_gui.wizards.device_dialog import NO_IMU_TEXT, DeviceDialog

CAMERAS = [CameraDevice("/dev/video0", "Firefly left"), CameraDevice("/dev/video2", "Firefly right")]
PORTS = [SerialPortInfo("/dev/ttyACM0", "Arduino Nano Every")]


@pytest.fixture
def present(monkeypatch):
    """What the fake system lists; tests change it to see Refresh pick it up."""
    devices = {"cameras": list(CAMERAS), "ports": list(PORTS)}
    monkeypatch.setattr(device_dialog, "list_cameras", lambda: devices["cameras"])
    monkeypatch.setattr(device_dialog, "list_serial_ports", lambda extra=(): devices["ports"])
    return devices


@pytest.fixture
def recording(tmp_path):
    """Two seeded 480x270 image pairs, the thesis calibration at that size and one at 960x540."""
    rng = np.random.default_rng(3)
    for k in range(2):
        for eye in ("left", "right"):
            cv2.imwrite(str(tmp_path / f"{eye}_{k}.png"), rng.integers(0, 255, (270, 480, 3), dtype=np.uint8))
    save_calibration(thesis_calibration().scaled(0.25), tmp_path / "calib.yaml")
    save_calibration(thesis_calibration().scaled(0.5), tmp_path / "calib_960.yaml")
    return tmp_path


def open_dialog(qtbot, config=None) -> DeviceDialog:
    dialog = DeviceDialog(config)
    qtbot.addWidget(dialog)
    dialog.show()
    qtbot.waitUntil(lambda: dialog.refresh_button.isEnabled(), timeout=5000)      # the listing worker is done
    return dialog


def type_into(qtbot, edit, text) -> None:
    edit.clear()
    qtbot.keyClicks(edit, text)


def choose(combo, data) -> None:
    combo.setCurrentIndex(combo.findData(data))


def test_folder_choice_tests_one_frame_and_ok_gives_the_config(qtbot, present, recording):
    dialog = open_dialog(qtbot)
    choose(dialog.mode, "folder")
    assert not dialog.ok_button.isEnabled() and not dialog.test_button.isEnabled()
    assert dialog.reason.text() == "Choose the left image pattern and the right image pattern."
    type_into(qtbot, dialog.left_images.edit, str(recording / "left_*.png"))
    type_into(qtbot, dialog.right_images.edit, str(recording / "right_*.png"))
    assert dialog.test_button.isEnabled() and not dialog.ok_button.isEnabled()
    assert dialog.reason.text().startswith("Choose the stereo calibration file")
    type_into(qtbot, dialog.calibration.edit, str(recording / "calib.yaml"))
    assert dialog.ok_button.isEnabled()
    choose(dialog.port, "/dev/ttyACM0")
    assert dialog.reason.text() == "Complete: OK opens these devices."
    dialog.fps.setValue(25.0)

    qtbot.mouseClick(dialog.test_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: "per eye" in dialog.test_status.text(), timeout=5000)
    assert dialog.test_status.text() == "Read one frame pair of 480x270 per eye; it matches the calibration."

    qtbot.mouseClick(dialog.ok_button, Qt.MouseButton.LeftButton)
    assert dialog.result() == QDialog.DialogCode.Accepted
    assert dialog.config() == RigConfig(mode="folder", left=str(recording / "left_*.png"),
                                        right=str(recording / "right_*.png"), fps=25.0, serial_port="/dev/ttyACM0",
                                        calibration_path=str(recording / "calib.yaml"))


def test_test_reports_a_calibration_of_another_size_in_one_sentence(qtbot, present, recording):
    config = RigConfig(mode="folder", left=str(recording / "left_*.png"), right=str(recording / "right_*.png"),
                       calibration_path=str(recording / "calib_960.yaml"))
    dialog = open_dialog(qtbot, config)
    qtbot.mouseClick(dialog.test_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: "per eye" in dialog.test_status.text(), timeout=5000)
    text = dialog.test_status.text()
    assert text.startswith("The frames are 480x270 per eye but the calibration") and "960x540" in text
    assert "red" in dialog.test_status.styleSheet()
    type_into(qtbot, dialog.calibration.edit, str(recording / "calib.yaml"))
    assert dialog.test_status.text() == ""            # the report belonged to the old choice


def test_incomplete_or_impossible_choices_keep_ok_disabled_with_the_reason(qtbot, present):
    dialog = open_dialog(qtbot, RigConfig(calibration_path="c.yaml"))
    assert _chosen_pair(dialog) == ("/dev/video0", "/dev/video2")        # the two cameras listed, in order
    assert dialog.ok_button.isEnabled() and dialog.reason.text().startswith("Complete, without an IMU")
    choose(dialog.right_camera, "/dev/video0")
    assert not dialog.ok_button.isEnabled()
    assert dialog.reason.text() == "The left and right cameras are the same device; choose two different ones."
    choose(dialog.right_camera, "/dev/video2")
    dialog.frame_width.setValue(1920)
    assert not dialog.ok_button.isEnabled() and "frame width and height" in dialog.reason.text()
    dialog.frame_height.setValue(1080)
    assert dialog.ok_button.isEnabled() and dialog.config().frame_size == (1920, 1080)
    dialog.baud.setEditText("")
    assert not dialog.ok_button.isEnabled() and dialog.reason.text().startswith("The baud rate must be a whole number")
    dialog.baud.setEditText("460800")
    choose(dialog.mode, "stacked")
    assert dialog.reason.text() == "Choose the camera that delivers both eyes."
    dialog.stacked_camera.setEditText("rtsp://endoscope/stream")
    assert dialog.ok_button.isEnabled()
    config = dialog.config()
    assert (config.mode, config.device, config.baudrate, config.serial_port) == ("stacked", "rtsp://endoscope/stream",
                                                                                  460800, None)
    qtbot.mouseClick(dialog.buttons.button(dialog.buttons.StandardButton.Cancel), Qt.MouseButton.LeftButton)
    assert dialog.result() == QDialog.DialogCode.Rejected


def _chosen_pair(dialog):
    return dialog.config().left, dialog.config().right


def test_a_stored_choice_comes_back_even_with_devices_that_are_not_listed(qtbot, present):
    stored = RigConfig(mode="pair", left="1", right="/dev/video2", frame_size=(1280, 720), fps=60.0,
                       serial_port="/tmp/imu-link", baudrate=115200, calibration_path="c.yaml", probe_path="p.yaml")
    dialog = open_dialog(qtbot, RigConfig.from_dict(stored.to_dict()))
    assert dialog.config() == stored
    assert dialog.right_camera.currentText() == "/dev/video2 - Firefly right"
    choose(dialog.port, None)
    assert dialog.port.currentText() == NO_IMU_TEXT and dialog.config().serial_port is None


def test_refresh_lists_what_was_plugged_in_and_keeps_the_choice(qtbot, present):
    dialog = open_dialog(qtbot, RigConfig(mode="stacked", device="/dev/video2", calibration_path="c.yaml"))
    assert dialog.stacked_camera.count() == 2 and dialog.port.count() == 2
    present["cameras"].append(CameraDevice("/dev/video4", "USB capture"))
    present["ports"].append(SerialPortInfo("/dev/ttyUSB0", "FTDI"))
    qtbot.mouseClick(dialog.refresh_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: dialog.refresh_button.isEnabled() and dialog.stacked_camera.count() == 3, timeout=5000)
    assert dialog.port.findData("/dev/ttyUSB0") > 0
    assert dialog.config().device == "/dev/video2"


def test_browse_buttons_fill_the_fields(qtbot, present, recording, monkeypatch):
    dialog = open_dialog(qtbot)
    monkeypatch.setattr(QFileDialog, "getOpenFileName", lambda *args: (str(recording / "calib.yaml"), ""))
    monkeypatch.setattr(QFileDialog, "getExistingDirectory", lambda *args: str(recording))
    qtbot.mouseClick(dialog.calibration.button, Qt.MouseButton.LeftButton)
    assert dialog.calibration.edit.text() == str(recording / "calib.yaml")
    choose(dialog.mode, "folder")
    type_into(qtbot, dialog.left_images.edit, "elsewhere/left_*.png")
    qtbot.mouseClick(dialog.left_images.button, Qt.MouseButton.LeftButton)
    qtbot.mouseClick(dialog.right_images.button, Qt.MouseButton.LeftButton)
    assert dialog.left_images.edit.text() == str(recording / "left_*.png")
    assert dialog.right_images.edit.text() == str(recording / "*.png")


def test_replay_a_recorded_session_needs_only_the_session(qtbot, present, tmp_path):
    dialog = open_dialog(qtbot)
    dialog.mode.setCurrentIndex(dialog.mode.findData("replay"))
    assert not dialog.ok_button.isEnabled() and "recorded session" in dialog.reason.text()
    dialog.replay_session.edit.setText(str(tmp_path / "s.h5"))
    dialog.replay_speed.setValue(2.0)
    assert dialog.ok_button.isEnabled() and "replays the session's video and IMU" in dialog.reason.text()
    assert not dialog.test_button.isEnabled()                      # its video is checked when the replay opens it
    config = dialog.config()
    assert (config.mode, config.left, config.speed) == ("replay", str(tmp_path / "s.h5"), 2.0)
    assert RigConfig.from_dict(config.to_dict()) == config
