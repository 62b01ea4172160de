"""``snreg-gui``: start the desktop app (``--demo`` for the hardware-free phantom demo)."""

from __future__ import annotations

import argparse
import sys

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QApplication, QLabel, QMainWindow

from snreg import __version__
from snreg_gui.acquisition_screen import AcquisitionScreen
from snreg_gui.acquisition_worker import THESIS_FIXES_PER_NODE, AcquisitionWorker, start_worker, stop_worker
from snreg.demo.rig import DemoRig


class MainWindow(QMainWindow):
    """The main window: in demo mode the acquisition screen on the simulated rig.

    Without ``--demo`` there is no device selection yet, so it says so. ``fixes_per_node`` is the
    "Store SN" window (thesis: 60); ``rig`` lets tests pass a rig with a shorter schedule.
    """

    def __init__(self, session_path: str | None = None, demo: bool = False, *, rig: DemoRig | None = None,
                 fixes_per_node: int = THESIS_FIXES_PER_NODE):
        super().__init__()
        mode = "demo" if demo else (session_path or "no session")
        self.setWindowTitle(f"snreg {__version__} - {mode}")
        self.resize(1400, 800)
        self.rig = self.worker = self._thread = None
        if not demo:
            text = QLabel("snreg\n\nCamera and IMU selection is not built yet: start with --demo for the simulated rig.")
            text.setAlignment(Qt.AlignmentFlag.AlignCenter)
            self.setCentralWidget(text)
            self.statusBar().showMessage("ready")
            return
        self.rig = rig or DemoRig(session_path)
        self.acquisition = AcquisitionScreen(self.rig.imu, fixes_per_node)
        self.setCentralWidget(self.acquisition)
        self.worker = AcquisitionWorker(self.rig.frame_source, self.rig.calibration, self.rig.probe, self.rig.chain,
                                        self.rig.imu, self.rig.session, self.rig.fps, fixes_per_node)
        queued = Qt.ConnectionType.QueuedConnection         # explicit: the worker lives in another thread
        self.worker.frame_processed.connect(self.acquisition.show_result, queued)
        self.worker.node_stored.connect(self.acquisition.add_node, queued)
        self.worker.store_failed.connect(self.acquisition.show_store_problem, queued)
        self.worker.source_stopped.connect(self.statusBar().showMessage, queued)
        self.acquisition.store_requested.connect(self.worker.store_node, queued)
        self.acquisition.fixes_per_node_changed.connect(self.worker.set_max_fixes, queued)
        self.worker.frame_processed.connect(self._first_frame, queued)
        QApplication.instance().aboutToQuit.connect(self.shutdown)
        self._thread = start_worker(self.worker)
        self.statusBar().showMessage("demo mode: no hardware; rendering the phantom")

    def _first_frame(self) -> None:
        self.statusBar().showMessage("demo mode: no hardware")
        self.worker.frame_processed.disconnect(self._first_frame)

    def closeEvent(self, event) -> None:
        self.shutdown()
        super().closeEvent(event)

    def shutdown(self) -> None:
        """Stop the worker, then the devices, and close the session file; safe to call twice."""
        if self._thread is not None:
            stop_worker(self.worker, self._thread)
            self._thread = None
        if self.rig is not None:
            self.rig.close()
            self.rig = None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="snreg-gui", description="snreg acquisition app")
    parser.add_argument("--demo", action="store_true", help="simulated devices, no hardware")
    parser.add_argument("session", nargs="?", help="session file to create (.h5); demo default: a new file in the temp folder")
    args = parser.parse_args(argv)
    app = QApplication.instance() or QApplication(sys.argv[:1])
    window = MainWindow(args.session, demo=args.demo)
    window.show()
    status = app.exec()
    window.shutdown()
    return status


if __name__ == "__main__":
    sys.exit(main())
