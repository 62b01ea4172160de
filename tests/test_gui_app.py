"""The main window's orchestration (issue 6): sessions (recent files, layout, continue, refusals), the hardware rig
chosen in the device dialog, calibration results applied, and the Store SN / undo keys a foot pedal can send."""

import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from PySide6.QtCore import QSettings, Qt
from PySide6.QtWidgets import QDialog

from snreg.camera import save_calibration, thesis_calibration
from snreg.chain import ChainCalibration
from snreg.demo.renderer import ProbePose, StereoRenderer
from snreg.demo.rig import DemoRig
from snreg.demo.scene import Schedule
from snreg.imu.monitor import ImuSnapshot
from snreg.probe import default_probe_model
from snreg.rig import RigConfig
from snreg.session import Session
from snreg.workflow.acquisition import FrameOutcome, StoreCheck
from snreg_gui.acquisition.screen import AcquisitionScreen
from snreg_gui.acquisition.worker import FrameResult, StoreRequest
from snreg_gui.app import MainWindow

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)


@pytest.fixture
def settings(tmp_path):
    return QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)


def recorded_session(path, n_nodes=2):
    with Session.create(path, case_id="phantom-07") as session:
        for k in range(n_nodes):
            session.add_intraop_node(f"SN{k + 1}", "OBT R", [float(k), 0.0, 250.0], spread_mm=0.2, n_frames=60)
    return path


@pytest.mark.slow
def test_recent_sessions_and_the_window_layout_are_remembered(qtbot, tmp_path, settings):
    path = recorded_session(tmp_path / "old.h5")
    first = MainWindow(settings=settings)
    qtbot.addWidget(first)
    with qtbot.waitExposed(first):
        first.show()
    assert "no session" in first.windowTitle()
    with qtbot.waitSignal(first.review.loaded, timeout=10_000):
        first.open_for_review(str(path))
    assert first.tabs.currentWidget() is first.review
    assert first.windowTitle().endswith("reviewing old.h5") and "no session" not in first.windowTitle()
    assert first.tabs.tabText(first.tabs.indexOf(first.review)) == "Review: old.h5"
    height = 690                                            # within the offscreen screen (800x800) and a 1024x700 one
    first.resize(first.minimumWidth(), height)
    remembered = (first.width(), first.height())
    assert remembered[1] == height                          # the loaded review fits a 1024x700 screen
    first.shutdown()

    second = MainWindow(settings=settings)
    qtbot.addWidget(second)
    with qtbot.waitExposed(second):
        second.show()
    assert second.recent.paths() == [str(path.resolve())]
    second._fill_recent()
    assert [a.text() for a in second.recent_menu.actions()] == [str(path.resolve())]
    assert (second.width(), second.height()) == remembered
    assert second.tabs.currentWidget() is second.review                     # the tab last shown
    path.unlink()                                                             # a file gone is no longer offered
    assert second.recent.paths() == []
    second.shutdown()


@pytest.mark.slow
def test_continue_session_shows_its_nodes_and_records_into_it(qtbot, tmp_path, settings):
    path = recorded_session(tmp_path / "case.h5")
    window = MainWindow(str(tmp_path / "demo.h5"), demo=True, rig=DemoRig(schedule=Schedule(rest_frames=30)),
                        fixes_per_node=10, settings=settings)
    qtbot.addWidget(window)
    window.continue_session(str(path))
    screen = window.acquisition
    assert window.session.path == path and window.session.writable
    assert [screen.nodes.item(r, 0).text() for r in range(screen.nodes.rowCount())] == ["SN1", "SN2"]
    assert screen.undo_button.isEnabled()
    qtbot.mouseClick(screen.undo_button, Qt.MouseButton.LeftButton)              # undo reaches the resumed session
    qtbot.waitUntil(lambda: screen.nodes.rowCount() == 1, timeout=30_000)
    window.shutdown()
    with Session.open(path) as session:
        assert session.intraop_nodes().ids == ["SN1"]


@pytest.mark.slow
def test_a_damaged_session_or_a_bad_case_id_is_refused_in_a_sentence(qtbot, tmp_path, settings):
    path = recorded_session(tmp_path / "torn.h5")
    path.write_bytes(path.read_bytes()[:1500])
    window = MainWindow(settings=settings)
    qtbot.addWidget(window)
    window.continue_session(str(path))
    assert window.session is None and "recover" in window.statusBar().currentMessage()
    window.set_session(window._create(tmp_path / "new.h5", "Jane Doe"))
    assert window.session is None and "pseudonymous" in window.statusBar().currentMessage()
    assert not (tmp_path / "new.h5").exists()
    window.shutdown()
    demo = MainWindow(str(path), demo=True, settings=settings)                    # the demo never overwrites a file
    qtbot.addWidget(demo)
    assert demo.session is None and "already exists" in demo.statusBar().currentMessage()
    demo.shutdown()


@pytest.mark.slow
def test_the_hardware_rig_chosen_in_the_device_dialog_runs_the_same_acquisition(qtbot, tmp_path, settings, monkeypatch):
    """Image folders stand in for the cameras; everything after the source is the real path."""
    calibration = thesis_calibration().scaled(0.5)
    renderer = StereoRenderer(calibration, default_probe_model())
    left, right = renderer.render(ProbePose.make([-10.0, 0.0, 90.0], [0.9, -0.3, 0.4]))
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"left_{k}.png"), left)
        cv2.imwrite(str(tmp_path / f"right_{k}.png"), right)
    save_calibration(calibration, tmp_path / "calib.yaml")
    config = RigConfig(mode="folder", left=str(tmp_path / "left_*.png"), right=str(tmp_path / "right_*.png"),
                       calibration_path=str(tmp_path / "calib.yaml"), fps=10.0)

    class ChosenDialog:
        def __init__(self, stored, parent=None):
            self.stored = stored

        def exec(self):
            return QDialog.DialogCode.Accepted

        def config(self):
            return config

    monkeypatch.setattr("snreg_gui.wizards.device_dialog.DeviceDialog", ChosenDialog)
    window = MainWindow(str(tmp_path / "case.h5"), settings=settings)
    qtbot.addWidget(window)
    assert window.session is not None and window.acquisition is None           # a session, no devices yet
    results = []
    window.wizards.select_devices()
    window.worker.frame_processed.connect(results.append)
    qtbot.waitUntil(lambda: len(results) >= 3 or "rendered all" in window.statusBar().currentMessage()
                    or "ended" in window.statusBar().currentMessage(), timeout=20_000)
    qtbot.waitUntil(lambda: len(results) == 3, timeout=5_000)
    assert all(r.outcome.fix is not None for r in results)
    assert window.acquisition.imu_health is not None
    qtbot.waitUntil(lambda: "absent" in window.acquisition.imu_health.text(), timeout=2_000)
    assert RigConfig.from_dict(__import__("json").loads(settings.value("devices/config"))) == config
    window.shutdown()


@pytest.mark.slow
def test_calibration_results_reach_the_rig_and_the_session(qtbot, tmp_path, settings):
    window = MainWindow(str(tmp_path / "demo.h5"), demo=True, rig=DemoRig(schedule=Schedule(rest_frames=30)),
                        settings=settings)
    qtbot.addWidget(window)
    window.wizards.stereo()
    wizard = window.wizards.active
    assert window.worker is None                                              # acquisition pauses for the wizard
    proposed = Path(wizard.save_page.path_edit.text())                        # next to the session, not ./
    assert proposed.parent == tmp_path.resolve() and proposed.name.startswith("demo_stereo_")
    new = thesis_calibration().scaled(0.5)
    wizard.save_page.saved_path = proposed                                    # as Finish leaves it
    wizard.calibrated.emit(new)
    wizard.reject()
    qtbot.waitUntil(lambda: window.worker is not None, timeout=10_000)         # and comes back after it
    assert window.rig.calibration is new
    np.testing.assert_allclose(window.session.calibration()["stereo"].K1, new.K1)
    notice = window.calibration_notice.text()                                 # said in words, in a box
    assert f"saved to {proposed} and stored in the session demo.h5 and applied" in notice
    window.calibration_notice.accept()
    chain = ChainCalibration.manual(trocar_camera_mm=150.0)
    window.apply_chain(chain)
    assert window.rig.chain is chain and "150.0 mm" in window.statusBar().currentMessage()
    assert f"saved in the session {window.session.path} and applied" in window.calibration_notice.text()
    window.shutdown()


class LevelImu:
    def snapshot(self):
        return ImuSnapshot("streaming", "", 208.0, 0.0, (0.0, 0.0, 0.0), np.eye(3), 1, 0)


def ready_result(fixes: int) -> FrameResult:
    from snreg.tracking import ProbeFix
    fix = ProbeFix(np.array([0.0, 0.0, 90.0]), np.array([0.0, 0.0, 120.0]), np.array([0.0, 0.0, 1.0]), 1.0,
                   "triangulation", 3)
    outcome = FrameOutcome(0, fix, "", np.array([0.0, 0.0, 248.0]), fixes, 0.2, True, False, 5.0, store_check=StoreCheck(""))
    rgb = np.zeros((54, 96, 3), np.uint8)
    return FrameResult(outcome, rgb, rgb, None, None, LevelImu().snapshot(), 0.0, 30.0, time.perf_counter_ns())


def test_foot_pedal_and_undo_keys(qtbot):
    screen = AcquisitionScreen(LevelImu(), fixes_per_node=5)
    qtbot.addWidget(screen)
    with qtbot.waitActive(screen):                                             # shortcuts act in the active window
        screen.show()
        screen.activateWindow()
    screen.label_edit.setText("EXT L")
    screen.counts_edit.setText("1520")
    screen.show_result(ready_result(5))
    assert screen.store_button.isEnabled() and "held still" in screen.store_reason.text()
    with qtbot.waitSignal(screen.store_requested) as stored:
        qtbot.keyClick(screen, Qt.Key.Key_F5)                                  # what a USB foot pedal sends
    assert stored.args == [StoreRequest("EXT L", 1520.0, "F5")]
    assert not screen.store_button.isEnabled() and screen.store_reason.text() == "storing..."
    with qtbot.assertNotEmitted(screen.undo_requested):
        qtbot.keyClick(screen, Qt.Key.Key_Z, Qt.KeyboardModifier.ControlModifier)   # nothing stored yet
    screen.counts_edit.setText("many")
    screen.show_store_problem("Not stored: only 3 of 5 valid fixes so far.")
    screen.request_store()
    assert "must be a number" in screen.store_status.text()


@pytest.mark.parametrize("argv, fragment", [(["--errors", "thesis"], "add --demo"), (["--replay"], "--replay needs"),
                                            (["s.h5", "--replay", "--speed", "0"], "--speed"),
                                            (["--demo", "--errors", "/dev/zero"], "not a regular file"),
                                            (["--camera", "surgery"], "add --demo"),
                                            (["--demo", "--camera", "moving"], "invalid choice")])
def test_the_command_line_refuses_a_bad_start_before_any_window(argv, fragment, capsys):
    from snreg_gui.__main__ import main

    with pytest.raises(SystemExit) as ended:
        main(argv)
    assert ended.value.code == 2 and fragment in capsys.readouterr().err


def test_a_node_stored_while_register_again_is_off_puts_the_feeds_hot_spots_out_of_date_at_once(qtbot, tmp_path,
                                                                                                 settings,
                                                                                                 pelvic_nodes):
    """The panel re-reads the nodes only when next shown, but the acquisition screen must not go on listing and drawing
    as current the hot spots of a registration that no longer answers the nodes stored (one of them just found)."""
    from snreg.nodes import NodeSet, write_nodes
    from snreg_gui.registration.navigation import OUT_OF_DATE

    xyz, labels = pelvic_nodes
    write_nodes(NodeSet.from_xyz(xyz, labels, prefix="P"), tmp_path / "preop.csv")
    window = MainWindow(str(tmp_path / "case.h5"), settings=settings)
    qtbot.addWidget(window)
    panel = window.registration
    panel.load_preop(str(tmp_path / "preop.csv"))
    qtbot.waitUntil(lambda: not panel.busy and panel.preop_box.nodes is not None, timeout=15_000)
    for k in range(4):                                                   # P5 and P6 not found yet
        window.session.add_intraop_node(f"SN{k + 1}", labels[k], xyz[k] + [0.5, -0.5, 0.0])
    panel.refresh_intraop()
    with qtbot.waitSignal(panel.registered, timeout=15_000):
        panel.run()
    assert [t.preop_id for t in panel.navigation.targets] == ["P5", "P6"] and not panel.navigation.stale
    panel.auto_rerun.setChecked(False)
    assert window.tabs.currentWidget() is not panel                      # the panel is not re-read now
    with qtbot.waitSignal(panel.missing_changed) as missing:
        window.session.add_intraop_node("SN5", labels[4], xyz[4])
        window._nodes_changed()                                          # as the worker's node_stored calls it
    assert missing.args[0] == [] and panel.navigation.stale == OUT_OF_DATE
    window.shutdown()
