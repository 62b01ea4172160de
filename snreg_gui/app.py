"""The desktop app's main window (``snreg-gui``, started by :mod:`snreg_gui.__main__`). Tabs for acquisition, registration and offline review; menus for sessions,
devices and the calibration wizards.

Why one window: in the operating room the technician records nodes, then registers them against the SPECT
without leaving the app; offline, the same window reviews a saved session. The window owns the session
and the rig (demo or hardware) and restarts the acquisition worker whenever either changes.

The camera's insertion (issue 27), when tracked, goes on across a restart of the worker with the same calibration and
chain (a switch toggled, a wizard closed without a new calibration): the camera may have slid since the start. A new
stereo or trocar calibration starts it again from the new chain's distance.

A calibration applied while nodes are stored is said plainly, with the offer to re-express them under it
(:mod:`snreg.workflow.chain_change`); the title names the session file in full and closing while recording asks first
(:mod:`snreg_gui.window_closing`), as an accidental close would end a surgical session.
"""

from __future__ import annotations

import gc
import os
import sys
import tempfile
import time
from pathlib import Path

from PySide6.QtCore import QSettings, Qt, Signal
from PySide6.QtGui import QAction, QKeySequence
from PySide6.QtWidgets import QApplication, QLabel, QMainWindow, QMessageBox, QTabWidget, QVBoxLayout, QWidget

from snreg.demo.rig import DemoRig
from snreg.session import Session
from snreg.workflow.acquisition import THESIS_FIXES_PER_NODE
from snreg_gui.acquisition.options import AcquisitionOptions
from snreg_gui.acquisition.screen import AcquisitionScreen
from snreg_gui.acquisition.worker import AcquisitionWorker, start_worker, stop_worker
from snreg_gui.common import wheel_guard
from snreg_gui.common.live_link import LinkState, LiveLinkControl
from snreg_gui.common.recent import RecentSessions
from snreg_gui.registration.demo_spect import DemoSpect
from snreg_gui.registration.panel import RegistrationPanel
from snreg_gui.review.screen import ReviewScreen
from snreg_gui.window_calibration import CalibrationApplying
from snreg_gui.window_closing import WindowClosing
from snreg_gui.window_sessions import SessionActions
from snreg_gui.wizards.launcher import WizardLauncher

# The GUI thread shares the GIL with the tracking worker and the IMU reader. At Python's default 5 ms switch
# interval a paint, which re-enters Python many times, can wait 5 ms at each entry; 1 ms keeps the GUI thread's
# stalls short (measured with the heartbeat in tests/test_gui_acquisition.py).
GIL_SWITCH_INTERVAL_S = 0.001

NO_RIG_TEXT = ("No cameras or IMU chosen yet.\n\nDevices > Select cameras and IMU... for the real rig, "
               "or start with --demo for the simulated one.")


class MainWindow(WindowClosing, SessionActions, CalibrationApplying, QMainWindow):
    """The app. ``demo``: the simulated rig and a new session (``session_path`` or a file in the temp folder).
    Without ``demo``, an existing ``session_path`` opens for review and a new one is created for recording.
    ``rig`` lets tests pass a rig with a shorter schedule; ``settings`` an isolated QSettings."""

    navigation_for_worker = Signal(object)  # the hot spots not found yet (NavigationState), to the worker's thread

    def __init__(self, session_path: str | None = None, demo: bool = False, *, rig=None,
                 fixes_per_node: int = THESIS_FIXES_PER_NODE, settings: QSettings | None = None,
                 replay: bool = False, speed: float = 1.0):
        super().__init__()
        wheel_guard.install(QApplication.instance())
        sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
        self.settings = settings or QSettings("snreg", "snreg")
        self.recent = RecentSessions(self.settings)
        self.fixes_per_node = fixes_per_node
        self.options = AcquisitionOptions(self.settings, self)
        self.rig = self.session = self.worker = self.acquisition = None
        self._kept_insertion = None      # the camera's insertion the last worker tracking it followed
        self.error_sources: dict = {}    # stored node id -> its covariance by source (the acquisition's advice)
        self._thread = None
        self._waiting_for_frames = False
        self._registration_stale = False
        self._end_confirmed = False
        self.close_prompt: QMessageBox | None = None
        self.calibration_prompt: QMessageBox | None = None
        self.calibration_notice: QMessageBox | None = None   # "saved to ... and applied" after a wizard's Finish
        self.tabs = QTabWidget()
        self._acquisition_tab = QWidget()
        QVBoxLayout(self._acquisition_tab)
        self.registration = RegistrationPanel()
        self.review = ReviewScreen()
        self.tabs.addTab(self._acquisition_tab, "Acquisition")
        self.tabs.addTab(self.registration, "Registration")
        self.tabs.addTab(self.review, "Review")
        self.setCentralWidget(self.tabs)
        self.tabs.currentChanged.connect(self._refresh_registration)
        self.registration.missing_changed.connect(self._missing_changed)
        self.registration.navigation_changed.connect(self.navigation_for_worker)
        self.wizards = WizardLauncher(self)
        self.live_link = LiveLinkControl(self.settings, self, self._link_state)
        self.registration.navigation_changed.connect(self.live_link.follow_navigation)
        self._menus()
        self._wire_review()
        self.live_link.failed.connect(self.statusBar().showMessage)
        self.options.switched.connect(self._option_switched)
        self.registration.registered.connect(self._send_registration)
        self.registration.preop_box.nodes_changed.connect(self._preop_changed)
        self.registration.preop_box.landmarks_changed.connect(      # a landmark file: the live link's PreopLandmarks
            lambda _: self._preop_changed(self.registration.preop_box.nodes))
        room = self.screen().availableGeometry()                  # never larger than the screen (1024 x 700)
        self.resize(min(1500, room.width()), min(900, room.height()))
        self._restore_layout()
        QApplication.instance().aboutToQuit.connect(self.shutdown)
        self._show_placeholder(NO_RIG_TEXT)
        if replay:
            self.replay(session_path, speed)
        elif demo:
            self.rig = rig or DemoRig(hold_rests=True)
            stamp = f"{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"      # two demos started in one second
            path = session_path or Path(tempfile.gettempdir()) / f"snreg-demo-{stamp}.h5"
            self.set_session(self._create(path, "phantom-demo"))
            if self.session is not None:               # else the status bar says why the file was refused
                self.demo_spect = DemoSpect(self)
                self.statusBar().showMessage(f"demo mode: no hardware; rendering the phantom; recording into "
                                             f"{self.session.path}")
        elif session_path and Path(session_path).exists():
            self.open_for_review(session_path)
        elif session_path:
            self.set_session(self._create(session_path, Path(session_path).stem))
        else:
            self.statusBar().showMessage("ready")
        self._update_title()
        self.live_link.restore()
        gc.freeze()        # the objects of start-up (Qt wrappers, modules) are left out of later collections,
                           # so a full collection during acquisition walks only what came after (shorter stalls)

    # -- menus ---------------------------------------------------------------
    def _menus(self) -> None:
        file = self.menuBar().addMenu("&File")
        self._action(file, "&New session...", self.new_session, QKeySequence.StandardKey.New)
        self._action(file, "&Continue session...", self.continue_session)
        self._action(file, "&Open session for review...", self.choose_review, QKeySequence.StandardKey.Open)
        self.recent_menu = file.addMenu("Recent sessions")
        self.recent_menu.aboutToShow.connect(self._fill_recent)
        file.addSeparator()
        self._action(file, "&Quit", self.close, QKeySequence.StandardKey.Quit)
        devices = self.menuBar().addMenu("&Devices")
        self._action(devices, "Select cameras and IMU...", self.wizards.select_devices)
        devices.addAction(self.live_link.action)
        devices.addAction(self.options.record_video)
        devices.addAction(self.options.track_insertion)
        calibrate = self.menuBar().addMenu("&Calibrate")
        self._action(calibrate, "Stereo cameras (checkerboard)...", self.wizards.stereo)
        self._action(calibrate, "Trocar distance...", self.wizards.trocar)

    def _action(self, menu, text, slot, shortcut=None) -> QAction:
        action = menu.addAction(text)
        action.triggered.connect(slot)
        if shortcut is not None:
            action.setShortcut(shortcut)
        return action

    def _option_switched(self, sentence: str) -> None:
        """Video recording or insertion tracking switched: from the next frame on (a video segment recorded so far
        is closed)."""
        if self.worker is not None:
            self.restart_acquisition()
        self.statusBar().showMessage(sentence)

    def set_session(self, session: Session | None) -> None:
        """Record into ``session`` from now on (the previous one is closed)."""
        if session is None:
            return
        self._stop_acquisition()
        if self.session is not None:
            self.session.close()
        self.session = session
        self.error_sources.clear()
        self.recent.add(session.path)
        if self.rig is not None:
            stored = session.calibration()
            self.rig.chain = stored.get("chain", self.rig.chain)
        self.registration.set_session(session)
        self.review.follow(session.path)
        self.live_link.reset_state()
        self.statusBar().showMessage(f"recording into {session.path} (case {session.case_id})")
        self._update_title()
        self._start_acquisition()

    # -- rig and acquisition -------------------------------------------------
    def set_rig(self, rig) -> None:
        """Use ``rig`` (demo or hardware) from now on; the previous one is closed."""
        self._stop_acquisition()
        if self.rig is not None:
            self.rig.close()
        self.rig = rig
        if self.session is not None:
            self.session.set_calibration(stereo=rig.calibration, chain=rig.chain)
        self._update_title()
        self._start_acquisition()

    @property
    def demo(self) -> bool:
        """Running on a simulated rig (for what the window says about itself)."""
        return self.rig is not None and self.rig.simulated

    def pause_acquisition(self) -> None:
        """Stop the acquisition worker (a wizard needs the cameras), saying "paused for calibration";
        :meth:`restart_acquisition` resumes."""
        self._stop_acquisition()
        if self.acquisition is not None:
            self.acquisition.set_paused(True)

    def restart_acquisition(self) -> None:
        """After a calibration changed the rig: the worker starts again with it."""
        self._stop_acquisition()
        self._start_acquisition()

    def _start_acquisition(self) -> None:
        if self.rig is None or self.session is None:
            self._show_placeholder(NO_RIG_TEXT if self.rig is None else "No session: File > New session...")
            return
        limits = self.options.limits()
        rig = self.rig
        preparing = (lambda: rig.preparing) if isinstance(rig, DemoRig) else None     # the demo's tour rendering
        self.acquisition = AcquisitionScreen(rig.imu, self.fixes_per_node, limits.max_spread_mm,
                                             self.options.untracked_text(rig), self.error_sources,
                                             preparing=preparing)
        self.acquisition.set_nodes(self.session.intraop_records(kind=None))      # the landmarks too, marked
        self.acquisition.set_landmark_names(self.registration.preop_box.landmarks)
        self._show_in_acquisition_tab(self.acquisition)
        kept = self._kept_insertion
        self.worker = AcquisitionWorker(self.rig.frame_source, self.rig.calibration, self.rig.probe, self.rig.chain,
                                        self.rig.imu, self.session, self.rig.fps, self.fixes_per_node, limits,
                                        self.options.record_video.isChecked(),
                                        track_insertion=self.options.tracks_insertion(self.rig),
                                        resume_insertion=kept and kept.on(self.rig.calibration, self.rig.chain))
        queued = Qt.ConnectionType.QueuedConnection         # explicit: the worker lives in another thread
        self.navigation_for_worker.connect(self.worker.set_navigation, queued)
        self._missing_changed(self.registration.missing_nodes)
        self.navigation_for_worker.emit(self.registration.navigation)
        self.worker.frame_processed.connect(self.acquisition.show_result, queued)
        self.worker.node_stored.connect(self.acquisition.add_node, queued)
        self.worker.node_error_sources.connect(self.acquisition.add_error_sources, queued)
        self.worker.node_removed.connect(self.acquisition.remove_node, queued)
        self.worker.node_stored.connect(self._nodes_changed, queued)
        if isinstance(rig, DemoRig):            # the demo's technician lifts the probe once its node is stored
            self.worker.node_stored.connect(lambda node: rig.release_rest(), Qt.ConnectionType.DirectConnection)
        self.worker.node_removed.connect(self._nodes_changed, queued)
        self.worker.store_failed.connect(self.acquisition.show_store_problem, queued)
        self.worker.store_confirm.connect(self.acquisition.ask_to_confirm, queued)
        self.worker.store_override_offered.connect(self.acquisition.offer_override, queued)
        self.acquisition.max_spread_changed.connect(self.worker.set_max_spread, queued)
        self.acquisition.max_spread_changed.connect(self.options.set_max_spread)
        self.worker.source_stopped.connect(self.statusBar().showMessage, queued)
        self.worker.source_stopped.connect(self.acquisition.show_source_stopped, queued)
        self.acquisition.store_requested.connect(self.worker.store_node, queued)
        self.acquisition.undo_requested.connect(self.worker.undo, queued)
        self.acquisition.fixes_per_node_changed.connect(self.worker.set_fixes_per_node, queued)
        self.worker.frame_processed.connect(self._first_frame, queued)
        for signal, slot in ((self.worker.frame_processed, self.live_link.show_result),
                             (self.worker.node_stored, self.live_link.add_node),
                             (self.worker.node_removed, self.live_link.remove_node)):
            signal.connect(slot, queued)                # the link's calls return at once, in the GUI thread
        self.live_link.state_changed.connect(self.acquisition.show_link_state)
        self.acquisition.show_link_state(self.live_link.state_text)
        self._waiting_for_frames = True
        self._thread = start_worker(self.worker)

    def _missing_changed(self, missing: list) -> None:
        """The SPECT nodes the latest registration left unpaired go to the acquisition screen and to 3D Slicer (the
        feeds draw them from the worker's thread: ``navigation_for_worker``)."""
        if self.acquisition is not None:
            self.acquisition.show_missing(missing)
        self.live_link.set_missing(missing)

    def _nodes_changed(self, *_) -> None:
        """The registration panel follows the stored nodes: it registers again at once when it says so (the missing
        nodes then update on the acquisition screen), else it is redrawn when next shown, its result's hot spots out of
        date on the acquisition screen at once; so is the review of it."""
        self.review.live_changed()
        if self.registration.auto_rerun.isChecked():
            self._registration_stale = False
            self.registration.rerun_after_store()
            return
        self._registration_stale = True
        self.registration.nodes_changed_unseen()
        self._refresh_registration()

    def _refresh_registration(self, *_) -> None:
        if self._registration_stale and self.tabs.currentWidget() is self.registration:
            self._registration_stale = False
            self.registration.refresh_intraop()

    def _preop_changed(self, nodes) -> None:
        """Preop nodes and their landmarks to the live link; the landmarks' names first in Store landmark's list."""
        self.live_link.set_preop_nodes(nodes)
        self.live_link.set_preop_landmarks(self.registration.preop_box.landmarks)
        if self.acquisition is not None:
            self.acquisition.set_landmark_names(self.registration.preop_box.landmarks)

    def _send_registration(self, result) -> None:
        """A registration done goes to 3D Slicer as current only while it answers the nodes stored now: one that a
        node stored while it ran made out of date is not sent (the link stopped giving the previous one already)."""
        if self.registration.current_result is result:
            self.live_link.set_registration(result, self.registration.pairs_line())

    def _link_state(self) -> LinkState:
        """What a live-link client sees first: the stored nodes and landmarks, the preop nodes and landmarks, the
        registration shown while it answers them (with its pairs line) and the hot spots it left unfound."""
        records = self.session.intraop_records(kind=None) if self.session is not None else []
        result, box = self.registration.current_result, self.registration.preop_box
        return LinkState(records, box.nodes, box.landmarks,
                         None if result is None else (result, self.registration.pairs_line()),
                         list(self.registration.missing_nodes))

    def _stop_acquisition(self) -> None:
        self._waiting_for_frames = False        # a frame signal still queued after the stop finds nothing to say
        if self._thread is not None:
            stop_worker(self.worker, self._thread)
            self._kept_insertion = self.worker.kept_insertion or self._kept_insertion
            self._thread = None
            self.worker = None

    def _first_frame(self) -> None:
        if not self._waiting_for_frames or self.session is None:     # a frame queued before the session ended
            return
        self._waiting_for_frames = False
        if not self.demo:
            text = f"recording into {self.session.path}"
        elif self.rig.description.startswith("demo"):
            text = f"demo mode: no hardware; recording into {self.session.path}"
        else:                                        # a replay: say what is replayed and where it goes
            text = f"{self.rig.description}: recording into {self.session.path.name}"
        self.statusBar().showMessage(text)

    def _show_placeholder(self, text: str) -> None:
        label = QLabel(text)
        label.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self._show_in_acquisition_tab(label)

    def _show_in_acquisition_tab(self, widget: QWidget) -> None:
        layout = self._acquisition_tab.layout()
        while layout.count():
            old = layout.takeAt(0).widget()
            if old is not None:
                old.hide()                  # at once: deleteLater waits for the event loop to come round
                old.deleteLater()
        layout.addWidget(widget)

    # -- window --------------------------------------------------------------
    def _restore_layout(self) -> None:
        geometry = self.settings.value("window/geometry")
        if geometry is not None:
            self.restoreGeometry(geometry)
        state = self.settings.value("window/state")
        if state is not None:
            self.restoreState(state)
        self.tabs.setCurrentIndex(int(self.settings.value("window/tab", 0)))

    def shutdown(self) -> None:
        """Remember the layout, stop the worker, then the devices, and close the session file; safe to call twice."""
        self.settings.setValue("window/geometry", self.saveGeometry())
        self.settings.setValue("window/state", self.saveState())
        self.settings.setValue("window/tab", self.tabs.currentIndex())
        self._stop_acquisition()
        self.live_link.stop(remember=False)
        self.wizards.shutdown()
        self.registration.shutdown()
        self.review.shutdown()
        if self.rig is not None:
            self.rig.close()
            self.rig = None
        if self.session is not None:
            self.session.close()
            self.session = None
