"""The wizard's calibrate page: the stereo calibration in a worker, its figures, and views to drop.

Why: the technician must judge a calibration before saving it (thesis §4.2): overall RMS, each
view's left/right reprojection and 3D reconstruction errors with the suspicious ones flagged as
``snreg calibrate stereo`` flags them, the check on its own views (epipolar and reconstruction
errors, :mod:`snreg.calibration.check`), warnings about near-identical views and a provisional
calibration from too few distinct views, the baseline and focal lengths; and rerun it without the
views that spoil it. :func:`~snreg.calibration.stereo.calibrate_stereo` searches the captured
full-size images again and may take seconds, so it runs in a Worker behind a busy bar.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
from PySide6.QtCore import Qt
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (QLabel, QProgressBar, QPushButton, QTableWidget, QTableWidgetItem, QVBoxLayout,
                               QWizardPage)

from snreg.calibration.checkerboard import Board
from snreg.calibration.stereo import SUSPECT_FACTOR, StereoResult, calibrate_stereo, drop_views
from snreg_gui.common.workers import Worker
from snreg_gui.wizards.stereo.capture import CapturedView

COLUMNS = ("drop", "left px", "right px", "recon mm", "note")
_SUSPECT_COLOUR = QColor(255, 220, 200)


@dataclass(frozen=True)
class _Outcome:
    """A calibration run's result or the one sentence why it failed, tagged with the run it answers."""

    run: int
    result: StereoResult | None
    problem: str = ""


def _tagged(run: int, fn: Callable[..., StereoResult], *args, **kwargs) -> _Outcome:
    """``fn(*args, **kwargs)`` as an :class:`_Outcome` of run ``run`` (runs in the worker thread)."""
    try:
        return _Outcome(run, fn(*args, **kwargs))
    except (ValueError, cv2.error) as err:
        return _Outcome(run, None, (str(err).strip().splitlines() or [type(err).__name__])[-1])   # OpenCV: last line


class CalibratePage(QWizardPage):
    """Runs the calibration on entry; ``result`` is the latest :class:`StereoResult` (None while none)."""

    def __init__(self, views: Callable[[], Sequence[CapturedView]], board: Callable[[], Board],
                 run_worker: Callable[[Worker], None]):
        super().__init__()
        self.setTitle("Calibrate")
        self.setSubTitle("Check the errors; tick views that spoil the calibration and recalibrate without them.")
        self._views, self._board, self._run_worker = views, board, run_worker
        self.result: StereoResult | None = None
        self._run = 0
        self._busy = False
        self.progress = QProgressBar()
        self.progress.setRange(0, 0)                 # busy indicator: calibrate_stereo reports no progress
        self.status = QLabel("")
        self.summary = QLabel("")
        self.summary.setWordWrap(True)                  # a warning line is long: wrapped, never cut at 1024x700
        self.summary.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.verticalHeader().setVisible(False)
        self.recalibrate_button = QPushButton("Recalibrate without the checked views")
        layout = QVBoxLayout(self)
        for widget in (self.progress, self.status, self.summary, self.table, self.recalibrate_button):
            layout.addWidget(widget)
        self.recalibrate_button.clicked.connect(self.recalibrate)
        self.table.itemChanged.connect(lambda _: self._update_buttons())
        self._update_buttons()

    def initializePage(self) -> None:
        views = self._views()
        self._start(f"Calibrating from {len(views)} views ...", calibrate_stereo,
                    [v.left_grey for v in views], [v.right_grey for v in views], self._board(),
                    left_names=[f"view {i + 1} (left)" for i in range(len(views))],
                    right_names=[f"view {i + 1} (right)" for i in range(len(views))])

    def cleanupPage(self) -> None:
        """Going back to capture more: forget this calibration (a late answer of a running one is ignored)."""
        self._run += 1
        self._busy = False
        self.result = None
        self._show_result()

    def isComplete(self) -> bool:
        return self.result is not None and not self._busy

    def checked_view_ids(self) -> list[int]:
        """View ids (indices among the captured views) whose drop box is ticked."""
        return [int(self.result.view_ids[row]) for row in range(self.table.rowCount())
                if self.table.item(row, 0).checkState() == Qt.CheckState.Checked]

    def recalibrate(self) -> None:
        drop = self.checked_view_ids() if self.result is not None else []
        if drop and not self._busy:
            self._start(f"Recalibrating without view(s) {', '.join(str(v + 1) for v in drop)} ...",
                        drop_views, self.result, drop)

    # -- worker ---------------------------------------------------------------------
    def _start(self, message: str, fn: Callable[..., StereoResult], *args, **kwargs) -> None:
        self._run += 1
        self._busy = True
        self.status.setText(message)
        self.progress.setVisible(True)
        self._update_buttons()
        self.completeChanged.emit()
        worker = Worker(_tagged, self._run, fn, *args, **kwargs)
        worker.returned.connect(self._finish, Qt.ConnectionType.QueuedConnection)
        worker.errored.connect(self._fail, Qt.ConnectionType.QueuedConnection)
        self._run_worker(worker)

    def _finish(self, outcome: _Outcome) -> None:
        if outcome.run != self._run:
            return                                   # answer to a run the user has left
        self._busy = False
        if outcome.result is not None:
            self.result = outcome.result
            self.status.setText("")
        else:
            self.status.setText(f"Calibration failed: {outcome.problem}")
        self._show_result()
        self.completeChanged.emit()

    def _fail(self, message: str) -> None:
        self._busy = False
        self.status.setText(f"Calibration failed unexpectedly: {message}; go back and capture the views again.")
        self._show_result()
        self.completeChanged.emit()

    # -- display --------------------------------------------------------------------
    def _show_result(self) -> None:
        self.progress.setVisible(self._busy)
        result = self.result
        self.table.blockSignals(True)
        self.table.setRowCount(0)
        if result is None:
            self.summary.setText("")
        else:
            self.summary.setText(_summary(result))
            errors = result.view_errors_px
            suspect = result.suspect_views
            repeats = dict(result.repeated_views)
            self.table.setRowCount(result.n_views)
            for row, view in enumerate(result.view_ids):
                drop = QTableWidgetItem(f"view {view + 1}")
                drop.setFlags(Qt.ItemFlag.ItemIsEnabled | Qt.ItemFlag.ItemIsUserCheckable)
                drop.setCheckState(Qt.CheckState.Unchecked)
                cells = [drop] + [QTableWidgetItem(f"{v:.3f}") for v in (*errors[row], result.view_reconstruction_mm[row])]
                notes = [f"check: error over {SUSPECT_FACTOR:g}x the median"] if suspect[row] else []
                if int(view) in repeats:
                    notes.append(f"repeats view {repeats[int(view)] + 1}")
                cells.append(QTableWidgetItem("; ".join(notes)))
                for column, item in enumerate(cells):
                    if column:
                        item.setFlags(Qt.ItemFlag.ItemIsEnabled)
                    if suspect[row]:
                        item.setBackground(_SUSPECT_COLOUR)
                    self.table.setItem(row, column, item)
            self.table.resizeColumnsToContents()
        self.table.blockSignals(False)
        self._update_buttons()

    def _update_buttons(self) -> None:
        ticked = self.result is not None and self.table.rowCount() > 0 and bool(self.checked_view_ids())
        self.recalibrate_button.setEnabled(ticked and not self._busy)


def _summary(result: StereoResult) -> str:
    """The figures of a calibration, its check on its own views, and the warnings ``snreg calibrate stereo`` prints."""
    calib = result.calibration
    skipped = (f"\nBoard not found at full size in {', '.join(result.skipped)}: left out." if result.skipped else "")
    warnings = "".join(f"\nWarning: {warning}." for warning in result.warnings())
    return (f"{result.n_views} views ({result.distinct_views} distinct); RMS reprojection {result.rms_px:.3f} px "
            f"(left {result.eye_rms_px[0]:.3f}, right {result.eye_rms_px[1]:.3f} px)\n"
            f"reconstruction error {result.reconstruction_error_mm:.3f} mm "
            f"(mean |triangulated square side - {result.board.square_mm:g} mm|)\n"
            f"check on its own views: {result.check.summary()}\n"
            f"baseline {calib.baseline_mm:.3f} mm; focal length left {calib.K1[0, 0]:.1f} x {calib.K1[1, 1]:.1f} px, "
            f"right {calib.K2[0, 0]:.1f} x {calib.K2[1, 1]:.1f} px" + skipped + warnings)
