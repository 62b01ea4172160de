"""The app's guarded Store SN, offscreen (issue 12): refusals in words and on record from the button, Space and F5 alike
(stale IMU, stale fix, spread over the limit), the confirmation near a stored node, "paused for calibration", the
calibration-change prompt and the question on close."""

import numpy as np
import pytest
from PySide6.QtCore import QSettings, Qt
from PySide6.QtWidgets import QMessageBox

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration, camera_to_trocar
from snreg.demo.scene import PhantomScene, Schedule
from snreg.imu.monitor import ImuAt, ImuSnapshot
from snreg.probe import default_probe_model
from snreg.sources import CallableSource
from snreg_gui.app import MainWindow

FIXES = 4
SCHEDULE = Schedule(rest_frames=10, move_frames=1, noise_variants=2)
KEYS = {"button": None, "Space": Qt.Key.Key_Space, "F5": Qt.Key.Key_F5}


class FakeImu:
    """An IMU whose samples are ``gap_s`` from every frame (3 s: it stopped sending)."""

    def __init__(self, gap_s: float = 0.0):
        self.gap_s = gap_s

    def start(self):
        return self

    def stop(self):
        pass

    def take_samples(self):
        return []

    def snapshot(self):
        state = "streaming" if self.gap_s < 1.0 else "disconnected"
        return ImuSnapshot(state, "", 208.0, self.gap_s, (0.0, 0.0, 0.0), np.eye(3), 1, 0)

    def orientation_at(self, t_host_ns):
        return ImuAt(np.eye(3), self.gap_s, self.snapshot().state)


class FakeRig:
    """Rendered phantom frames chosen by ``frames(index) -> scene index or None (black)``, a live feed."""

    simulated, description, fps, moving_camera = True, "test rig", 30.0, False

    def __init__(self, scene, frames, imu):
        self.scene, self.frames, self.imu = scene, frames, imu
        self.calibration, self.probe, self.chain = scene.renderer.calibration, default_probe_model(), ChainCalibration.manual()

    def frame_source(self):
        black = np.zeros_like(self.scene.render(0)[0])

        def render(index):
            k = self.frames(index)
            return (black, black) if k is None else self.scene.render(k)
        return CallableSource(render, self.fps, live=True, name="test feed")

    def close(self):
        pass


@pytest.fixture(scope="module")
def scene():
    scene = PhantomScene(thesis_calibration().scaled(0.5), default_probe_model(), SCHEDULE)
    for index in (0, 1, 11, 12):            # resting on nodes 0 and 1, both noise variants
        scene.render(index)
    return scene


def on_node(node):
    return lambda index: node * (SCHEDULE.rest_frames + SCHEDULE.move_frames) + index % 2


@pytest.fixture
def open_window(qtbot, tmp_path):
    windows = []

    def make(rig):
        settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
        window = MainWindow(str(tmp_path / f"case{len(windows)}.h5"), fixes_per_node=FIXES, settings=settings)
        qtbot.addWidget(window)
        window.set_rig(rig)
        with qtbot.waitActive(window):                     # the Store SN keys act in the active window
            window.show()
            window.activateWindow()
        windows.append(window)
        return window
    yield make
    for window in windows:
        window.shutdown()


def press(qtbot, screen, key):
    if KEYS[key] is None:
        qtbot.mouseClick(screen.store_button, Qt.MouseButton.LeftButton)
        return
    window = screen.window()
    if not window.isActiveWindow():                       # a dialog just closed (offscreen does not give it back)
        with qtbot.waitActive(window):
            window.activateWindow()
    qtbot.keyClick(screen, KEYS[key])


SCENARIOS = {
    "stale IMU": (on_node(0), 3.0, "the IMU is stale: no sample within 3.0 s of a frame (IMU disconnected)"),
    "stale fix": (lambda index: on_node(0)(index) if index < 60 else None, 0.0,          # probe gone after 2 s
                  "s old (no probe stripe"),
    "spread over the limit": (lambda index: on_node((index // 2) % 2)(index), 0.0, "the probe moved: the last 4 fixes"),
}


@pytest.mark.slow
@pytest.mark.parametrize("scenario", SCENARIOS)
def test_every_store_key_is_refused_in_words_and_on_record(qtbot, open_window, scene, scenario):
    frames, gap_s, reason = SCENARIOS[scenario]
    window = open_window(FakeRig(scene, frames, FakeImu(gap_s)))
    screen = window.acquisition
    qtbot.waitUntil(lambda: reason in screen.store_reason.text(), timeout=20_000)
    assert screen.store_reason.text().startswith("not ready: ") and screen.store_button.isEnabled()
    for key in KEYS:
        press(qtbot, screen, key)
        qtbot.waitUntil(lambda: screen.store_status.text().startswith(f"Refused ({key}): "), timeout=5_000)
        assert reason in screen.store_status.text()
    assert window.session.intraop_records() == []
    refused = window.session.events("store_refused")
    assert [event["trigger"] for event in refused] == list(KEYS)
    assert all(reason in event["reason"] for event in refused)


@pytest.mark.slow
def test_a_store_near_a_stored_node_asks_naming_it(qtbot, open_window, scene):
    window = open_window(FakeRig(scene, on_node(1), FakeImu()))
    screen = window.acquisition
    qtbot.waitUntil(lambda: screen.store_reason.text().startswith("ready"), timeout=20_000)
    screen.label_edit.setText("OBT L")
    press(qtbot, screen, "F5")
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == 1, timeout=5_000)
    qtbot.waitUntil(lambda: "SN1 is" in screen.store_reason.text() and "you will be asked" in screen.store_reason.text(),
                    timeout=5_000)
    for answer, rows in ((QMessageBox.StandardButton.No, 1), (QMessageBox.StandardButton.Yes, 2)):
        press(qtbot, screen, "Space")
        qtbot.waitUntil(lambda: screen.confirm_box is not None, timeout=5_000)
        assert screen.confirm_box.text().startswith("SN1 (OBT L) is already stored ")
        assert screen.confirm_box.text().endswith("mm from here. Store this as a new node anyway?")
        screen.confirm_box.done(answer)
        qtbot.waitUntil(lambda: screen.nodes.rowCount() == rows, timeout=5_000)
    assert [n.id for n in window.session.intraop_records()] == ["SN1", "SN2"]
    assert window.session.events("store_near_confirmed")[0]["near"] == "SN1"


@pytest.mark.slow
def test_paused_for_calibration_the_chain_change_prompt_and_the_question_on_close(qtbot, open_window, scene):
    window = open_window(FakeRig(scene, on_node(0), FakeImu()))
    screen = window.acquisition
    qtbot.waitUntil(lambda: screen.store_reason.text().startswith("ready"), timeout=20_000)
    press(qtbot, screen, "button")
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == 1, timeout=5_000)
    window.pause_acquisition()                                     # what a wizard does
    screen._last_arrival_ns = 1                                    # the last frame long ago: not "STALE" though
    screen._show_health()
    assert screen.video_health.text().startswith("camera: paused for calibration")
    assert "STALE" not in screen.video_health.text() and not screen.store_button.isEnabled()
    new = ChainCalibration.manual(trocar_camera_mm=171.5)
    window.session.set_calibration(chain=new)                      # the trocar wizard stores it, then the app applies it
    window.apply_chain(new)
    prompt = window.calibration_prompt
    assert prompt.text().startswith("The trocar calibration (chain) changed. SN1 was stored under the previous one")
    [reexpress] = [b for b in prompt.buttons() if prompt.buttonRole(b) == QMessageBox.ButtonRole.AcceptRole]
    assert reexpress.text() == "Re-express SN1"
    reexpress.click()
    [node] = window.session.intraop_records()
    np.testing.assert_allclose(node.xyz_trocar, camera_to_trocar(new, node.earth_from_imu, node.xyz_camera), atol=1e-9)
    assert "re-expressed SN1" in window.statusBar().currentMessage()
    window.restart_acquisition()
    window.close()
    assert window.close_prompt.text() == f"1 node and 0 landmarks stored, all saved in {window.session.path}; end the session?"
    [keep] = [b for b in window.close_prompt.buttons() if b.text() == "Keep recording"]
    keep.click()
    assert window.session is not None and window.close_prompt is None
    window.close()
    [end] = [b for b in window.close_prompt.buttons() if b.text() == "End the session"]
    end.click()
    assert window.session is None                                  # ended: the session file is closed
