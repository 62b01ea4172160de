"""The trocar wizard's live pages: the left feed, the IMU angles, the samples and a running fit.

Why: the technician pivots the endoscope in the trocar and must see, while doing it, whether the board (or the
tissue) is followed, how many samples there are and what they give, and accept once it is good enough. Capture and
fits run in :class:`~snreg_gui.common.workers.Worker` threads (:mod:`snreg.workflow.trocar_capture`,
:mod:`snreg.workflow.tissue_capture`, :mod:`snreg.calibration.trocar_fit`); the pages only show what comes back.
:class:`PivotPage` runs the pivot method over a board (recommended), :class:`ArcPage` the thesis's arc method
(eq. 14) on the same samples, :class:`TissuePage` the pivot method over tissue, with no board.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from PySide6.QtWidgets import (QGridLayout, QHBoxLayout, QLabel, QPushButton, QTableWidget, QTableWidgetItem,
                               QVBoxLayout, QWizardPage)

from snreg.calibration.pivot import GOOD_TILT_DEG
from snreg.calibration.tissue_pivot import GOOD_TURN_DEG
from snreg.calibration.trocar_fit import MIN_ARC_PAIRS, ArcFit, PivotFit, fit_arc, fit_pivot, fit_tissue_pivot
from snreg.geometry import euler_from_rotation
from snreg.workflow.tissue_capture import Restarts, TissueSample
from snreg.workflow.trocar_capture import MIN_SAMPLE_TURN_DEG, BoardFrame, PivotSample
from snreg_gui.common.feed_view import FeedView
from snreg_gui.common.table_headers import two_line_headers
from snreg_gui.common.workers import FitRunner, LiveLoop
from snreg_gui.wizards.trocar.pages import ChainChoice, PageId

_SAMPLE_COLUMNS = ("frame", "t (s)", "yaw", "pitch", "roll", "camera x", "camera y", "camera z")
_VERDICT_COLOURS = {"good": "#1a7f37", "check": "#b35900", "bad": "#c62828"}


class LivePage(QWizardPage):
    """Feed, IMU angles, samples table, Reset and Accept; subclasses show their fit in :attr:`estimate`.

    The page is complete (Next and Accept enabled) once its fit is acceptable; leaving it by Next or Accept
    hands :meth:`choice` to the wizard. Entering it from the method page starts with no samples. :attr:`capture`
    is the live loop that feeds it (the wizard runs it while the page is shown).
    """

    def __init__(self, capture: LiveLoop, fit: Callable, title: str, subtitle: str,
                 details: tuple[QLabel, ...] = ()):
        super().__init__()
        self.setTitle(title)
        self.setSubTitle(subtitle)
        self.capture = capture
        self.samples: list[PivotSample | TissueSample] = []
        self.fit: PivotFit | ArcFit | None = None
        self._fits = FitRunner(fit, self)
        self.feed = FeedView("left")
        self.imu_label = QLabel("IMU: waiting for the first frame")
        self.frame_note = QLabel("")
        self.sample_count = QLabel("samples: 0")
        self.table = QTableWidget(0, len(_SAMPLE_COLUMNS))
        self.table.setHorizontalHeaderLabels(_SAMPLE_COLUMNS)
        two_line_headers(self.table)            # all eight columns in the page's right column at 1024x700
        self.estimate = QLabel("")
        self.status = QLabel("")
        self.status.setWordWrap(True)
        self.reset_button, self.accept_button = QPushButton("Reset"), QPushButton("Accept")
        self.accept_button.setEnabled(False)
        self._layout(details)
        capture.frame_ready.connect(self._show_frame)
        capture.stopped.connect(self._show_stop)
        self._fits.fitted.connect(self._show_fit)
        self._fits.failed.connect(self.status.setText)
        self.reset_button.clicked.connect(self.reset)
        self.accept_button.clicked.connect(lambda: self.wizard().next())

    def _layout(self, details: tuple[QLabel, ...]) -> None:
        left = QVBoxLayout()
        left.addWidget(self.feed, 1)
        left.addWidget(self.imu_label)
        left.addWidget(self.frame_note)
        buttons = QHBoxLayout()
        buttons.addWidget(self.reset_button)
        buttons.addWidget(self.accept_button)
        right = QVBoxLayout()
        for widget in (self.sample_count, self.table, self.estimate, *details):
            if isinstance(widget, QLabel):
                widget.setWordWrap(True)
            right.addWidget(widget)
        right.addLayout(buttons)
        right.addWidget(self.status)
        grid = QGridLayout(self)
        grid.addLayout(left, 0, 0)
        grid.addLayout(right, 0, 1)
        grid.setColumnStretch(0, 3)
        grid.setColumnStretch(1, 2)

    def initializePage(self) -> None:
        self.reset()

    def isComplete(self) -> bool:
        return self.fit is not None and self.fit.acceptable

    def validatePage(self) -> bool:
        if not self.isComplete():
            return False
        self.wizard().set_choice(self.choice())
        return True

    def nextId(self) -> int:
        return PageId.SUMMARY

    def choice(self) -> ChainChoice:
        """The accepted chain with its quality, for the summary."""
        raise NotImplementedError

    def shutdown(self) -> None:
        """Wait for a running fit (closing the wizard)."""
        self._fits.shutdown()

    @property
    def fitting(self) -> bool:
        return self._fits.running

    def reset(self) -> None:
        """Forget the samples and the fit; the feed goes on."""
        self.samples, self.fit = [], None
        self._fits.reset()
        self.table.setRowCount(0)
        self.sample_count.setText("samples: 0")
        self.estimate.setText(f"pivot the endoscope about the trocar in two directions; a sample is kept "
                              f"each time the camera has turned {MIN_SAMPLE_TURN_DEG:g} degree or more")
        self.status.setText("")
        self._completeness_changed()

    def _is_current(self) -> bool:
        wizard = self.wizard()
        return wizard is not None and wizard.currentPage() is self

    def _show_frame(self, frame: BoardFrame) -> None:
        if not self._is_current():
            return
        self.feed.show_frame(frame.display_rgb, None, None)
        yaw, pitch, roll = frame.euler_deg
        self.imu_label.setText(f"IMU at frame {frame.index}: yaw {yaw:7.2f}, pitch {pitch:7.2f}, "
                               f"roll {roll:7.2f} degrees")
        self.frame_note.setText(frame.note)
        if frame.sample is not None:
            self._add_sample(frame.sample)

    def _add_sample(self, sample: PivotSample | TissueSample) -> None:
        self.samples.append(sample)
        row = self.table.rowCount()
        self.table.insertRow(row)
        seconds = (sample.t_host_ns - self.samples[0].t_host_ns) / 1e9
        cells = (str(sample.frame_index), f"{seconds:.2f}", *(f"{a:.2f}" for a in sample.euler_deg),
                 *(f"{v:.1f}" for v in sample.pose[:3, 3]))
        for column, text in enumerate(cells):
            self.table.setItem(row, column, QTableWidgetItem(text))
        self.table.scrollToBottom()
        self.sample_count.setText(f"samples: {len(self.samples)}")
        self._fits.request(np.array([s.pose for s in self.samples]), np.array([s.earth_from_imu for s in self.samples]))

    def _show_stop(self, message: str) -> None:
        if self._is_current():
            self.status.setText(f"The feed stopped ({message.rstrip('.')}); go Back, then Next to start it again.")

    def _show_fit(self, fit) -> None:
        self.fit = fit
        self.display_fit(fit)
        self._completeness_changed()

    def display_fit(self, fit) -> None:
        """Show ``fit`` in :attr:`estimate` (and the subclass's own labels)."""
        raise NotImplementedError

    def _completeness_changed(self) -> None:
        self.accept_button.setEnabled(self.isComplete())
        self.completeChanged.emit()


class PivotPage(LivePage):
    """The pivot method: trocar-camera distance, uncertainty, residual, verdict, and the IMU-camera rotation."""

    method = "pivot"          # the chain's method, as the summary and the session record it

    def __init__(self, capture: LiveLoop, fit: Callable = fit_pivot, title: str = "Pivot calibration",
                 subtitle: str = ("Keep the checkerboard still in view and pivot the endoscope about the trocar, "
                                  f"left-right and up-down, by {GOOD_TILT_DEG:g} degrees or more. Accept once the "
                                  "verdict is not bad.")):
        verdict, rotation = QLabel(""), QLabel("")
        super().__init__(capture, fit, title, subtitle, (verdict, rotation))
        self.verdict, self.rotation = verdict, rotation

    def reset(self) -> None:
        super().reset()
        self.verdict.setText("")
        self.rotation.setText("")

    def display_fit(self, fit: PivotFit) -> None:
        if fit.pivot is None:
            self.estimate.setText(f"no estimate yet from {fit.n_samples} samples: {fit.problem}")
            self.verdict.setText("")
            self.rotation.setText("")
            return
        pivot = fit.pivot
        colour = _VERDICT_COLOURS[pivot.verdict]
        self.verdict.setText(f'<span style="color:{colour}"><b>verdict: {pivot.verdict}</b></span>: {pivot.advice}')
        if fit.hand_eye is not None:
            yaw, pitch, roll = euler_from_rotation(fit.hand_eye.imu_from_camera)
            self.rotation.setText(f"IMU-camera rotation (yaw, pitch, roll): {yaw:.2f}, {pitch:.2f}, {roll:.2f} "
                                  f"degrees; RMS residual {fit.hand_eye.rms_deg:.2f} degrees over "
                                  f"{fit.hand_eye.n_pairs} pose pairs")
        else:
            self.rotation.setText(f"IMU-camera rotation not determined yet ({fit.rotation_problem}); "
                                  "the identity is assumed, as in the thesis")
        self.estimate.setText(f"trocar-camera distance {pivot.trocar_camera_mm:.2f} mm (standard error "
                              f"{pivot.distance_sd_mm:.2f} mm); RMS residual {pivot.rms_mm:.2f} mm over {pivot.n_used} "
                              f"of {fit.n_samples} samples; tilt range {pivot.tilt_range_deg:.1f} degrees")

    def choice(self) -> ChainChoice:
        pivot = self.fit.pivot
        rotation = ("measured from the IMU and camera turns" if self.fit.hand_eye is not None
                    else "identity assumed (not determined)")
        return ChainChoice(self.fit.chain, self.method,
                           f"verdict {pivot.verdict}: RMS residual {pivot.rms_mm:.2f} mm, standard error "
                           f"{pivot.distance_sd_mm:.2f} mm over {pivot.n_used} samples; "
                           f"IMU-camera rotation {rotation}")


class TissuePage(PivotPage):
    """The pivot method over tissue: the camera's own poses from the stereo video instead of a board's. Reset also
    starts the follower afresh from the view in sight (``restarts``, read by the capture thread); samples of an
    earlier start are in another tissue frame and are not taken."""

    method = "tissue"

    def __init__(self, capture: LiveLoop, restarts: Restarts):
        self._restarts, self._start = restarts, restarts.count
        super().__init__(capture, fit_tissue_pivot, "Turn the camera over tissue",
                         "Hold the endoscope's insertion and turn it about the trocar over still, textured tissue, "
                         f"left-right and up-down, by {GOOD_TURN_DEG:g} degrees or more, not faster than the feed "
                         "follows. Accept once the verdict is not bad.")

    def reset(self) -> None:
        self._start = self._restarts.restart()
        super().reset()

    def _add_sample(self, sample: TissueSample) -> None:
        if sample.start == self._start:
            super()._add_sample(sample)


class ArcPage(LivePage):
    """The thesis's arc method (eq. 14) on the camera origin as it swings about the trocar: median and IQR."""

    def __init__(self, capture: LiveLoop):
        super().__init__(capture, fit_arc, "Arc method (thesis eq. 14)",
                         "Keep the checkerboard still in view and swing the endoscope about the trocar without "
                         "rolling it about its axis (a roll biases the distance low). The IMU axes are taken as "
                         "aligned with the camera's, as in the thesis; the pivot method measures them.")

    def display_fit(self, fit: ArcFit) -> None:
        if fit.estimate is None:
            self.estimate.setText(f"no estimate yet from {fit.n_samples} samples: {fit.problem}")
            return
        estimate = fit.estimate
        wanted = "" if fit.acceptable else f" (at least {MIN_ARC_PAIRS} needed to accept)"
        self.estimate.setText(f"trocar-camera distance {estimate.distance_mm:.1f} mm (median), interquartile range "
                              f"[{estimate.q25_mm:.1f}, {estimate.q75_mm:.1f}] mm = {estimate.iqr_mm:.1f} mm, "
                              f"from {estimate.n_used} swings between {fit.n_samples} samples{wanted}")

    def choice(self) -> ChainChoice:
        estimate = self.fit.estimate
        return ChainChoice(self.fit.chain, "arc",
                           f"median of {estimate.n_used} swings, interquartile range [{estimate.q25_mm:.1f}, "
                           f"{estimate.q75_mm:.1f}] mm; IMU-camera axes aligned by eye (identity)")
