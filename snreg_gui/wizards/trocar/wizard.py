"""The trocar calibration wizard: the chain trocar <- IMU <- camera before surgery (thesis §3.5, §4.1).

Why: the technician calibrates the chain once per set-up, watching live whether the recording is good
enough. Pages: the method; the pivot method (recommended: pivot calibration of solvePnP board poses and
the IMU-camera rotation from the same recording, :mod:`snreg.calibration.pivot`), the thesis's arc
method (eq. 14, :func:`snreg.calibration.trocar.arc_distance`) on the same live samples, or manual
entry (thesis: 460 mm and 158 mm); and a summary that saves the
:class:`~snreg.chain.ChainCalibration` into the session (durable at once) and emits ``chain_calibrated``.

The feed runs only while a live page is shown; capture and fits run in worker threads; closing,
cancelling or finishing closes the source and waits for every thread. Usage, with the simulated
recording (:mod:`snreg.demo.pivot_scene`; a camera source and an
:class:`~snreg.imu.monitor.ImuMonitor` go in the same places)::

    calibration = thesis_calibration().scaled(0.5)
    board = Board(10, 7, 10.0)                      # inner corners, as OpenCV counts them
    scene = PivotScene(calibration, board)
    wizard = TrocarWizard(scene.frame_source, scene.imu, calibration, board, session=session)
    wizard.chain_calibrated.connect(use_chain)      # a ChainCalibration
    wizard.show()
"""

from __future__ import annotations

from collections.abc import Callable

from PySide6.QtCore import Signal
from PySide6.QtWidgets import QWizard

from snreg.calibration.checkerboard import Board
from snreg.camera import StereoCalibration
from snreg.sources import FrameSource
from snreg.workflow.trocar_capture import capture_samples
from snreg_gui.common.workers import LiveLoop
from snreg_gui.wizards.trocar.live import ArcPage, LivePage, PivotPage
from snreg_gui.wizards.trocar.pages import ChainChoice, ManualPage, MethodPage, PageId, SummaryPage

__all__ = ["TrocarWizard"]


class TrocarWizard(QWizard):
    """Emits ``chain_calibrated(ChainCalibration)`` when finished; ``session``: a writable
    :class:`~snreg.session.Session` to store the chain in, or None. ``imu.snapshot()`` must give
    ``earth_from_imu`` (3, 3) and ``euler_deg``; ``make_source`` is called in the capture thread."""

    chain_calibrated = Signal(object)

    def __init__(self, make_source: Callable[[], FrameSource], imu, calibration: StereoCalibration, board: Board, *,
                 session=None, parent=None):
        super().__init__(parent)
        self.setWindowTitle("Trocar calibration")
        self.choice: ChainChoice | None = None
        self._capture = LiveLoop(capture_samples, make_source, imu, calibration, board, parent=self)
        self.method_page, self.manual_page = MethodPage(), ManualPage()
        self.pivot_page, self.arc_page = PivotPage(self._capture), ArcPage(self._capture)
        self.summary_page = SummaryPage(session)
        for page_id, page in ((PageId.METHOD, self.method_page), (PageId.PIVOT, self.pivot_page),
                              (PageId.ARC, self.arc_page), (PageId.MANUAL, self.manual_page),
                              (PageId.SUMMARY, self.summary_page)):
            self.setPage(page_id, page)
        self.setStartId(PageId.METHOD)
        self.currentIdChanged.connect(self._feed_live_pages)
        self.accepted.connect(lambda: self.chain_calibrated.emit(self.choice.chain))
        self.finished.connect(self._shut_down)

    def set_choice(self, choice: ChainChoice) -> None:
        """The chain a method page settled on (called as it is left by Next or Accept)."""
        self.choice = choice

    @property
    def busy(self) -> bool:
        """Whether any of the wizard's threads (capture, fits, saving) is still running."""
        return (self._capture.running or self.pivot_page.fitting or self.arc_page.fitting
                or self.summary_page.saving)

    def _feed_live_pages(self, page_id: int) -> None:
        if isinstance(self.page(page_id), LivePage):
            self._capture.start()
        else:
            self._capture.stop()

    def _shut_down(self) -> None:
        """Close the source and wait for every thread (on finish, cancel and close)."""
        self._capture.shutdown()
        for page in (self.pivot_page, self.arc_page, self.summary_page):
            page.shutdown()
