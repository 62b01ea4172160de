"""The device dialog: which cameras (or recordings), IMU port, calibration and probe model the rig uses.

Why: before acquisition the technician picks the hardware from lists of what is plugged in, checks that a
frame pair comes through ("Test"), and confirms. The dialog only shows choices and reports; listing devices
and reading the test frame run in worker threads (:mod:`snreg.sources.devices`, :func:`snreg.rig.check_source`),
and it remembers nothing itself: the main window stores ``config().to_dict()`` (QSettings) and passes it back.
OK is enabled only when the choice is complete; the line above the buttons says what is still missing.

>>> dialog = DeviceDialog(RigConfig.from_dict(stored) if stored else None, parent=window)
>>> if dialog.exec():
...     rig = HardwareRig(dialog.config(), chain=session_chain)
...     settings.setValue("devices/config", json.dumps(dialog.config().to_dict()))
"""

from __future__ import annotations

from pathlib import Path

from PySide6.QtGui import QIntValidator
from PySide6.QtWidgets import (QComboBox, QDialog, QDialogButtonBox, QDoubleSpinBox, QFileDialog, QFormLayout,
                               QGroupBox, QHBoxLayout, QLabel, QLineEdit, QPushButton, QSpinBox, QStackedWidget,
                               QVBoxLayout, QWidget)

from snreg.imu.reader import DEFAULT_BAUD
from snreg.rig import CAMERA_MODES, RigConfig, check_source
from snreg.sources.capture import LAYOUTS
from snreg.sources.devices import list_cameras, list_serial_ports
from snreg_gui.common import file_places
from snreg_gui.common.workers import Worker, WorkerSet

MODE_TEXTS = {"pair": "Two cameras, one per eye", "stacked": "One camera delivering both eyes",
              "video": "Two video files (replay)", "folder": "Two image folders (replay)",
              "replay": "Replay a recorded session (its video and IMU)"}
LAYOUT_TEXTS = {"side_by_side": "side by side (left eye left)", "top_bottom": "top and bottom (left eye on top)"}
BAUD_RATES = (115200, DEFAULT_BAUD, 460800, 921600)
NO_IMU_TEXT = "none (no IMU)"
_VIDEO_FILTER = "Videos (*.avi *.mp4 *.mkv *.mov)"
_YAML = "(*.yaml *.yml *.xml)"
_WORKER_WAIT_MS = 10_000


def _list_devices(extra_ports: list[str]):
    """Cameras and serial ports present (in the worker: probing cameras can take seconds off Linux)."""
    return list_cameras(), list_serial_ports(extra=extra_ports)


def _chosen(combo: QComboBox) -> str:
    """The device of an editable list: the chosen item's, or the text typed in."""
    text = combo.currentText().strip()
    index = combo.currentIndex()
    if index >= 0 and combo.itemText(index) == combo.currentText():
        data = combo.itemData(index)
        return "" if data is None else str(data)
    return text


def _select(combo: QComboBox, value: str | None) -> None:
    """Choose the item whose device is ``value``, or type ``value`` in when it is not listed."""
    index = combo.findData(value) if value else -1
    if index < 0 and value:
        index = next((k for k in range(combo.count()) if str(combo.itemData(k)) == value), -1)
    if index >= 0:
        combo.setCurrentIndex(index)
    else:
        combo.setEditText(value or "")


def _device_combo() -> QComboBox:
    combo = QComboBox()
    combo.setEditable(True)
    combo.setInsertPolicy(QComboBox.InsertPolicy.NoInsert)
    combo.setMinimumContentsLength(28)
    return combo


class _PathField(QWidget):
    """A line edit with a Browse button that asks ``browse(current_text)`` for a new text (None: keep)."""

    def __init__(self, browse, placeholder: str = ""):
        super().__init__()
        self.edit = QLineEdit()
        self.edit.setPlaceholderText(placeholder)
        self.button = QPushButton("Browse...")
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.edit)
        layout.addWidget(self.button)
        self.button.clicked.connect(lambda: self._browse(browse))

    def _browse(self, browse) -> None:
        text = browse(self.edit.text().strip())
        if text:
            self.edit.setText(text)


class DeviceDialog(QDialog):
    """Choose the rig's devices and files; :meth:`config` gives the choice after OK. ``config`` fills the fields."""

    def __init__(self, config: RigConfig | None = None, parent=None):
        super().__init__(parent)
        self.setWindowTitle("Cameras and IMU")
        self.setMinimumWidth(640)
        config = config or RigConfig()
        self._workers = WorkerSet()
        self._tested: RigConfig | None = None      # the choice the last Test read
        self._test_worker: Worker | None = None
        self._build()
        self._set_fields(config)
        self._connect()
        self.refresh()
        self._update()

    # -- building ------------------------------------------------------------
    def _build(self) -> None:
        self.mode = QComboBox()
        for mode in CAMERA_MODES:
            self.mode.addItem(MODE_TEXTS[mode], mode)
        self.left_camera, self.right_camera, self.stacked_camera = _device_combo(), _device_combo(), _device_combo()
        self.layout_choice = QComboBox()
        for layout in LAYOUTS:
            self.layout_choice.addItem(LAYOUT_TEXTS[layout], layout)
        self.left_video = _PathField(lambda t: self._open_file("Left video file", t, _VIDEO_FILTER))
        self.right_video = _PathField(lambda t: self._open_file("Right video file", t, _VIDEO_FILTER))
        self.left_images = _PathField(lambda t: self._image_pattern("Folder of the left images", t), "folder/left_*.png")
        self.right_images = _PathField(lambda t: self._image_pattern("Folder of the right images", t),
                                       "folder/right_*.png")
        self.replay_session = _PathField(lambda t: self._open_file("Recorded session", t, "snreg sessions (*.h5)"),
                                         "session recorded with video (.h5)")
        self.replay_speed = QDoubleSpinBox()
        self.replay_speed.setRange(0.1, 10.0)
        self.replay_speed.setDecimals(1)
        self.replay_speed.setSuffix(" x recorded pace")
        self.pages = QStackedWidget()
        for rows in ((("left camera", self.left_camera), ("right camera", self.right_camera)),
                     (("camera", self.stacked_camera), ("layout", self.layout_choice)),
                     (("left video", self.left_video), ("right video", self.right_video)),
                     (("left images", self.left_images), ("right images", self.right_images)),
                     (("recorded session", self.replay_session), ("speed", self.replay_speed))):
            page = QWidget()
            form = QFormLayout(page)
            form.setContentsMargins(0, 0, 0, 0)
            for label, widget in rows:
                form.addRow(label, widget)
            self.pages.addWidget(page)
        self.frame_width, self.frame_height = QSpinBox(), QSpinBox()
        for spin in (self.frame_width, self.frame_height):
            spin.setRange(0, 16384)
            spin.setSpecialValueText("default")
        self.fps = QDoubleSpinBox()
        self.fps.setRange(1.0, 240.0)
        self.fps.setDecimals(1)
        self.fps.setSuffix(" fps")
        self.port = _device_combo()
        self.baud = QComboBox()
        self.baud.setEditable(True)
        self.baud.setValidator(QIntValidator(1, 10_000_000, self))
        self.baud.addItems([str(rate) for rate in BAUD_RATES])
        self.calibration = _PathField(lambda t: self._open_file("Stereo calibration", t, "Calibration " + _YAML),
                                      "calibration .yaml")
        self.probe = _PathField(lambda t: self._open_file("Probe model", t, "Probe model " + _YAML),
                                "default: the DROP-IN probe")
        self.refresh_button, self.test_button = QPushButton("Refresh"), QPushButton("Test")
        self.test_status = QLabel("")
        self.test_status.setWordWrap(True)
        self.reason = QLabel("")
        self.reason.setWordWrap(True)
        self.buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel)
        self.ok_button = self.buttons.button(QDialogButtonBox.StandardButton.Ok)
        self._lay_out()

    def _lay_out(self) -> None:
        cameras = QGroupBox("Cameras")
        form = QFormLayout(cameras)
        form.addRow("source", self.mode)
        form.addRow(self.pages)
        size = QHBoxLayout()
        size.addWidget(self.frame_width)
        size.addWidget(QLabel("x"))
        size.addWidget(self.frame_height)
        size.addStretch(1)
        form.addRow("frame size", size)
        form.addRow("frame rate", self.fps)
        imu = QGroupBox("IMU")
        imu_form = QFormLayout(imu)
        imu_form.addRow("serial port", self.port)
        imu_form.addRow("baud", self.baud)
        files = QGroupBox("Calibration")
        files_form = QFormLayout(files)
        files_form.addRow("stereo calibration", self.calibration)
        files_form.addRow("probe model", self.probe)
        actions = QHBoxLayout()
        actions.addWidget(self.refresh_button)
        actions.addWidget(self.test_button)
        actions.addWidget(self.test_status, 1)
        layout = QVBoxLayout(self)
        for box in (cameras, imu, files):
            layout.addWidget(box)
        layout.addLayout(actions)
        layout.addWidget(self.reason)
        layout.addWidget(self.buttons)

    def _set_fields(self, config: RigConfig) -> None:
        self.mode.setCurrentIndex(CAMERA_MODES.index(config.mode))
        self.pages.setCurrentIndex(CAMERA_MODES.index(config.mode))
        self.layout_choice.setCurrentIndex(LAYOUTS.index(config.layout))
        if config.mode == "pair":
            _select(self.left_camera, config.left)
            _select(self.right_camera, config.right)
        elif config.mode == "stacked":
            _select(self.stacked_camera, config.device)
        elif config.mode == "replay":
            self.replay_session.edit.setText(config.left)
        else:
            for field, text in zip(self._file_fields(config.mode), (config.left, config.right)):
                field.edit.setText(text)
        width, height = config.frame_size or (0, 0)
        self.frame_width.setValue(width)
        self.frame_height.setValue(height)
        self.fps.setValue(config.fps)
        self.replay_speed.setValue(config.speed)
        self._set_port_items([], config.serial_port)
        self.baud.setEditText(str(config.baudrate))
        self.calibration.edit.setText(config.calibration_path)
        self.probe.edit.setText(config.probe_path or "")

    def _file_fields(self, mode: str) -> tuple[_PathField, _PathField]:
        return (self.left_video, self.right_video) if mode == "video" else (self.left_images, self.right_images)

    def _connect(self) -> None:
        self.mode.currentIndexChanged.connect(self.pages.setCurrentIndex)
        for combo in (self.mode, self.layout_choice):
            combo.currentIndexChanged.connect(self._update)
        for combo in (self.left_camera, self.right_camera, self.stacked_camera, self.port, self.baud):
            combo.currentTextChanged.connect(self._update)
        for field in (*self._file_fields("video"), *self._file_fields("folder"), self.calibration, self.probe,
                      self.replay_session):
            field.edit.textChanged.connect(self._update)
        for spin in (self.frame_width, self.frame_height, self.fps, self.replay_speed):
            spin.valueChanged.connect(self._update)
        self.refresh_button.clicked.connect(self.refresh)
        self.test_button.clicked.connect(self.test)
        self.buttons.accepted.connect(self.accept)
        self.buttons.rejected.connect(self.reject)

    # -- the choice ----------------------------------------------------------
    def config(self) -> RigConfig:
        """The choice as shown; ValueError (one sentence) while a field holds an impossible value (OK disabled)."""
        mode = self.mode.currentData()
        left = right = device = ""
        if mode == "pair":
            left, right = _chosen(self.left_camera), _chosen(self.right_camera)
        elif mode == "stacked":
            device = _chosen(self.stacked_camera)
        elif mode == "replay":
            left = self.replay_session.edit.text().strip()
        else:
            left, right = (field.edit.text().strip() for field in self._file_fields(mode))
        width, height = self.frame_width.value(), self.frame_height.value()
        if (width == 0) != (height == 0) and mode in ("pair", "stacked"):
            raise ValueError("Give both the frame width and height, or leave both at default.")
        frame_size = (width, height) if width and height and mode in ("pair", "stacked") else None
        baud = self.baud.currentText().strip()
        if not baud.isdigit():
            raise ValueError(f"The baud rate must be a whole number such as {DEFAULT_BAUD}, not {baud!r}.")
        return RigConfig(mode=mode, left=left, right=right, device=device, layout=self.layout_choice.currentData(),
                         frame_size=frame_size, fps=self.fps.value(), serial_port=_chosen(self.port) or None,
                         baudrate=int(baud), calibration_path=self.calibration.edit.text().strip(),
                         probe_path=self.probe.edit.text().strip() or None, speed=self.replay_speed.value())

    def _current(self) -> tuple[RigConfig | None, str]:
        """The choice and what it still lacks ("" when complete); None and the reason when it is impossible."""
        try:
            config = self.config()
        except ValueError as err:
            return None, str(err)
        return config, config.missing

    def _update(self) -> None:
        config, reason = self._current()
        self.ok_button.setEnabled(config is not None and not reason)
        replaying = self.mode.currentData() == "replay"
        if not reason:
            reason = ("Complete: OK replays the session's video and IMU, with its calibration, into a new session."
                      if replaying else "Complete: OK opens these devices." if config.serial_port else
                      "Complete, without an IMU: the endoscope will be taken as held still; OK opens the cameras.")
        self.reason.setText(reason)
        is_camera = self.mode.currentData() in ("pair", "stacked")
        self.frame_width.setEnabled(is_camera)
        self.frame_height.setEnabled(is_camera)
        self.test_button.setEnabled(config is not None and not config.source_missing and self._test_worker is None
                                    and not replaying)
        if config != self._tested:
            self._show_test_status("")

    # -- workers (their signals go to bound methods, so the slots run in the GUI thread) ----------------
    def refresh(self) -> None:
        """List the cameras and serial ports again (in a worker); the current choices stay chosen."""
        self.refresh_button.setEnabled(False)
        port = _chosen(self.port)
        worker = Worker(_list_devices, [port] if port else [])
        worker.returned.connect(self._show_devices)
        worker.errored.connect(self._listing_failed)
        worker.finished.connect(self._listing_finished)
        self._run(worker)

    def test(self) -> None:
        """Open the chosen source, read one frame pair and report its size or the problem (in a worker)."""
        config, _ = self._current()
        if config is None or config.source_missing or self._test_worker is not None:
            return
        self._tested = config
        self._show_test_status("testing: opening the source and reading one frame pair ...")
        self._test_worker = Worker(check_source, config)
        self._test_worker.returned.connect(self._test_passed)
        self._test_worker.errored.connect(self._test_failed)
        self._test_worker.finished.connect(self._test_finished)
        self._run(self._test_worker)
        self._update()

    def _run(self, worker: Worker) -> None:
        self._workers.run(worker)

    def _listing_failed(self, message: str) -> None:
        self._show_test_status(f"Listing the devices failed ({message}); type the device names in.", error=True)

    def _listing_finished(self) -> None:
        self.refresh_button.setEnabled(True)

    def _test_passed(self, size) -> None:
        if self._current()[0] != self._tested:
            return
        match = ("it matches the calibration" if self._tested.calibration_path
                 else "choose a calibration made at this size")
        self._show_test_status(f"Read one frame pair of {size[0]}x{size[1]} per eye; {match}.")

    def _test_failed(self, message: str) -> None:
        if self._current()[0] == self._tested:
            self._show_test_status(message, error=True)

    def _test_finished(self) -> None:
        self._test_worker = None
        self._update()

    def _show_test_status(self, text: str, *, error: bool = False) -> None:
        self.test_status.setText(text)
        self.test_status.setStyleSheet("color: red" if error else "")

    def _show_devices(self, devices) -> None:
        cameras, ports = devices
        for combo in (self.left_camera, self.right_camera, self.stacked_camera):
            chosen = _chosen(combo)
            combo.blockSignals(True)
            combo.clear()
            for camera in cameras:
                combo.addItem(camera.text, str(camera.device))
            combo.blockSignals(False)
            _select(combo, chosen)
        if self.mode.currentData() == "pair" and not _chosen(self.left_camera) and len(cameras) >= 2:
            self.left_camera.setCurrentIndex(0)
            self.right_camera.setCurrentIndex(1)
        self._set_port_items(ports, _chosen(self.port) or None)
        self._update()

    def _set_port_items(self, ports, chosen: str | None) -> None:
        self.port.blockSignals(True)
        self.port.clear()
        self.port.addItem(NO_IMU_TEXT, None)
        for port in ports:
            self.port.addItem(port.text, port.device)
        self.port.blockSignals(False)
        if chosen:
            _select(self.port, chosen)
        else:
            self.port.setCurrentIndex(0)

    # -- browsing ------------------------------------------------------------
    def _open_file(self, title: str, current: str, file_filter: str) -> str | None:
        path, _ = QFileDialog.getOpenFileName(self, title, current or file_places.start_path(None),
                                              f"{file_filter};;All files (*)")
        file_places.remember(path)
        return path or None

    def _image_pattern(self, title: str, current: str) -> str | None:
        """A folder chosen, as a pattern that keeps the current file pattern (``*.png`` by default)."""
        folder = QFileDialog.getExistingDirectory(self, title, str(Path(current).parent) if current
                                                  else file_places.start_path(None))
        if not folder:
            return None
        file_places.remember(folder)
        name = Path(current).name if current and any(c in Path(current).name for c in "*?[") else "*.png"
        return str(Path(folder) / name)

    # -- closing -------------------------------------------------------------
    def done(self, result: int) -> None:
        """OK, Cancel, Escape and closing all end here: wait for the listing or test still running."""
        self._workers.shutdown(_WORKER_WAIT_MS)
        super().done(result)
