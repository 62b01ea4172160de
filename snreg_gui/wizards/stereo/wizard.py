"""The checkerboard stereo calibration wizard: set up the board, capture views live, calibrate, save.

Why: before surgery the technician calibrates the Firefly stereo endoscope by showing it a
checkerboard in many poses (thesis §3.3, §4.2: 30 views) and needs to see, while doing it, that the
views are good and varied, and to judge and save the result (docs/design.md, Calibration file). Pages:

1. Setup: inner corners (cols x rows, as OpenCV counts them), square size, target number of views.
2. Capture: both live feeds with the found corners, "Capture view" and auto-capture, a coverage map
   per eye, warnings for repeated views (:mod:`snreg_gui.wizards.stereo.capture`).
3. Calibrate: :func:`~snreg.calibration.stereo.calibrate_stereo` in a worker, RMS, per-view errors,
   drop views and recalibrate (:mod:`snreg_gui.wizards.stereo.calibrate`).
4. Save: :func:`~snreg.camera.save_calibration` to a YAML file, by default next to the session
   (:func:`snreg_gui.common.file_places.calibration_path`), never a bare relative name that lands wherever the
   app was started.

The feed is read and searched in a worker thread (``make_source`` is called there), and every worker
is stopped, and the source closed, when the wizard finishes, is cancelled or is closed.

>>> from snreg.demo.board_tour import board_feed
>>> wizard = StereoCalibrationWizard(board_feed, Board(10, 7, 10.0), target_views=30)
>>> wizard.calibrated.connect(lambda calibration: print(calibration.baseline_mm))
>>> wizard.show()
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
from PySide6.QtCore import Signal
from PySide6.QtWidgets import (QDialog, QDoubleSpinBox, QFileDialog, QFormLayout, QHBoxLayout, QLabel, QLineEdit,
                               QPushButton, QSpinBox, QVBoxLayout, QWizard, QWizardPage)

from snreg.calibration.checkerboard import THESIS_BOARD, Board
from snreg.calibration.stereo import MIN_VIEWS
from snreg.camera import save_calibration
from snreg.sources import FrameSource
from snreg_gui.common import file_places
from snreg_gui.common.workers import WorkerSet
from snreg_gui.wizards.stereo.calibrate import CalibratePage
from snreg_gui.wizards.stereo.capture import CapturePage

__all__ = ["StereoCalibrationWizard"]

_SHUTDOWN_WAIT_S = 120.0         # a running calibration cannot be interrupted; it ends within seconds


class SetupPage(QWizardPage):
    """Board (inner corners and square size) and the target number of views; complete when the board is valid."""

    def __init__(self, board: Board, target_views: int):
        super().__init__()
        self.setTitle("Checkerboard")
        self.setSubTitle("Count the inner corners as OpenCV does: a board of 11 x 8 squares has 10 x 7.")
        self.cols, self.rows = QSpinBox(), QSpinBox()
        for spin, value in ((self.cols, board.cols), (self.rows, board.rows)):
            spin.setRange(2, 60)
            spin.setValue(value)
        self.square_mm = QDoubleSpinBox()
        self.square_mm.setRange(0.1, 500.0)
        self.square_mm.setDecimals(2)
        self.square_mm.setSuffix(" mm")
        self.square_mm.setValue(board.square_mm)
        self.target_views = QSpinBox()
        self.target_views.setRange(MIN_VIEWS, 500)
        self.target_views.setValue(target_views)
        self.problem = QLabel("")
        self.problem.setStyleSheet("color: red")
        form = QFormLayout(self)
        form.setFieldGrowthPolicy(QFormLayout.FieldGrowthPolicy.FieldsStayAtSizeHint)   # numbers, not 730 px bars
        form.addRow("inner corners across (cols)", self.cols)
        form.addRow("inner corners down (rows)", self.rows)
        form.addRow("square size", self.square_mm)
        form.addRow("target number of views", self.target_views)
        form.addRow(self.problem)
        for spin in (self.cols, self.rows, self.square_mm):
            spin.valueChanged.connect(self._check)
        self._check()

    def board(self) -> Board:
        return Board(self.cols.value(), self.rows.value(), self.square_mm.value())

    def isComplete(self) -> bool:
        return not self.problem.text()

    def _check(self) -> None:
        try:
            self.board()
            self.problem.setText("")
        except ValueError:
            self.problem.setText("Columns and rows must differ (so the board's orientation is known); "
                                 "check the inner-corner count.")
        self.completeChanged.emit()


class SavePage(QWizardPage):
    """Where to write the calibration; Finish writes it (``saved_path``), or says why it cannot."""

    def __init__(self, calibrate_page: CalibratePage, default_path: Path):
        super().__init__()
        self.setTitle("Save")
        self.setSubTitle("Finish writes the calibration file (OpenCV YAML) and applies it: tracking uses it from "
                         "then on, and it is stored in the session.")
        self.setFinalPage(True)
        self._calibrate_page = calibrate_page
        self.saved_path: Path | None = None
        self._default_path = Path(default_path)
        self.path_edit = QLineEdit(str(default_path))
        self.browse_button = QPushButton("Browse ...")
        self.summary, self.status = QLabel(""), QLabel("")
        self.status.setStyleSheet("color: red")
        row = QHBoxLayout()
        row.addWidget(self.path_edit)
        row.addWidget(self.browse_button)
        layout = QVBoxLayout(self)
        layout.addWidget(self.summary)
        layout.addLayout(row)
        layout.addWidget(self.status)
        self.browse_button.clicked.connect(self._browse)

    def initializePage(self) -> None:
        result = self._calibrate_page.result
        self.summary.setText(f"{result.n_views} views, RMS {result.rms_px:.3f} px, "
                             f"baseline {result.calibration.baseline_mm:.3f} mm")
        self.status.setText("")

    def validatePage(self) -> bool:
        text = self.path_edit.text().strip()
        if not text:
            self.status.setText(f"Enter a file name for the calibration, e.g. {self._default_path}.")
            return False
        path = Path(text).expanduser().resolve()
        if path == self._default_path.resolve():
            path.parent.mkdir(parents=True, exist_ok=True)       # the default folder (~/snreg) on first use
        if not path.parent.is_dir():
            self.status.setText(f"The folder {path.parent} does not exist; choose another place.")
            return False
        if path.is_dir():
            self.status.setText(f"{path} is a folder; enter a file name such as calibration.yaml.")
            return False
        try:
            save_calibration(self._calibrate_page.result.calibration, path)
        except (cv2.error, OSError):
            pass
        if not path.is_file():
            self.status.setText(f"Cannot write {path}; choose a folder you may write to.")
            return False
        self.saved_path = path
        return True

    def _browse(self) -> None:
        path, _ = QFileDialog.getSaveFileName(self, "Save calibration", self.path_edit.text(), "Calibration (*.yaml *.yml)")
        if path:
            file_places.remember(path)
            self.path_edit.setText(path)


class StereoCalibrationWizard(QWizard):
    """Checkerboard stereo calibration on a live feed; emits ``calibrated(StereoCalibration)`` on Finish.

    ``make_source`` builds the stereo :class:`~snreg.sources.FrameSource` (called in a worker thread);
    ``board`` gives the setup page's defaults (thesis board 10 x 7 inner corners of 10 mm when None);
    ``save_path`` the file the save page proposes (next to the session; without one, in the last folder used
    or ``~/snreg``). After Finish, ``saved_path`` is where the calibration was written.
    """

    calibrated = Signal(object)

    def __init__(self, make_source: Callable[[], FrameSource], board: Board | None = None, *,
                 target_views: int = 30, save_path: Path | None = None, parent=None):
        super().__init__(parent)
        self.setWindowTitle("Stereo calibration")
        self._workers = WorkerSet()
        self.setup_page = SetupPage(board or THESIS_BOARD, target_views)
        self.capture_page = CapturePage(make_source, self.setup_page.board, self.setup_page.target_views.value,
                                        self._workers.run)
        self.calibrate_page = CalibratePage(lambda: self.capture_page.views, self.setup_page.board, self._workers.run)
        self.save_page = SavePage(self.calibrate_page, save_path or file_places.calibration_path(
            None, file_places.last_folder(), "stereo"))
        for page in (self.setup_page, self.capture_page, self.calibrate_page, self.save_page):
            self.addPage(page)
        self.currentIdChanged.connect(self._page_changed)
        self.resize(1200, 800)

    @property
    def saved_path(self) -> Path | None:
        """Where Finish wrote the calibration (None before)."""
        return self.save_page.saved_path

    def has_running_workers(self) -> bool:
        """Whether any of the wizard's threads (feed, calibration) is still running."""
        return self._workers.running

    def shutdown(self) -> None:
        """Stop the feed (closing its source) and wait for every worker; safe to call twice."""
        self.capture_page.stop_feed()
        self._workers.shutdown(round(_SHUTDOWN_WAIT_S * 1000))

    def done(self, result: int) -> None:
        """Finish, Cancel, Escape and closing the window all end here. Finish saves first (QWizard validates the
        save page inside ``done``): only a calibration saved is emitted, with :attr:`saved_path` set; a save that
        fails keeps the wizard open, saying why."""
        if result != QWizard.DialogCode.Accepted:
            self.shutdown()
            return super().done(result)
        if not self.validateCurrentPage():
            return
        self.shutdown()
        calibration = self.calibrate_page.result
        if calibration is not None:
            self.calibrated.emit(calibration.calibration)
        QDialog.done(self, result)             # not QWizard.done: it would validate (save) the page again

    def _page_changed(self, _page_id: int) -> None:
        self.capture_page.pause_feed(self.currentPage() is not self.capture_page)
