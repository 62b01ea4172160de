"""The trocar calibration wizard: the chain trocar <- IMU <- camera before surgery (thesis §3.5, §4.1).

Why: the technician calibrates the chain once per set-up, watching live whether the recording is good
enough. Pages: the method; the pivot method (recommended: pivot calibration of solvePnP board poses and
the IMU-camera rotation from the same recording, :mod:`snreg.calibration.pivot`), the same over tissue with
no board (the camera's own poses from the stereo video, :mod:`snreg.calibration.tissue_pivot`), the thesis's arc
method (eq. 14, :func:`snreg.calibration.trocar.arc_distance`) on the board's live samples, or manual
entry (thesis: 460 mm and 158 mm); and a summary that saves the
:class:`~snreg.chain.ChainCalibration` into the session (durable at once) and emits ``chain_calibrated``.

A feed runs only while a live page it feeds is shown (the board's, or the tissue's); capture and fits run in worker
threads; closing, cancelling or finishing closes the sources and waits for every thread. Usage, with the simulated
recordings (:mod:`snreg.demo.pivot_scene`, :mod:`snreg.demo.tissue_pivot`; a camera source and an
:class:`~snreg.imu.monitor.ImuMonitor` go in the same places, and the tissue's feed defaults to the board's)::

    calibration = thesis_calibration().scaled(0.5)
    board = Board(10, 7, 10.0)                      # inner corners, as OpenCV counts them
    scene, tissue = PivotScene(calibration, board), TissuePivotScene(calibration)
    wizard = TrocarWizard(scene.frame_source, scene.imu, calibration, board, session=session,
                          tissue_source=(tissue.frame_source, tissue.imu), probe=default_probe_model())
    wizard.chain_calibrated.connect(use_chain)      # a ChainCalibration
    wizard.show()
"""

from __future__ import annotations

from collections.abc import Callable

from PySide6.QtCore import Signal
from PySide6.QtWidgets import QWizard

from snreg.calibration.checkerboard import Board
from snreg.camera import StereoCalibration
from snreg.probe import ProbeModel
from snreg.sources import FrameSource
from snreg.workflow.tissue_capture import Restarts, capture_tissue_samples
from snreg.workflow.trocar_capture import capture_samples
from snreg_gui.common.workers import LiveLoop
from snreg_gui.wizards.trocar.live import ArcPage, LivePage, PivotPage, TissuePage
from snreg_gui.wizards.trocar.pages import ChainChoice, ManualPage, MethodPage, PageId, SummaryPage

__all__ = ["TrocarWizard"]


class TrocarWizard(QWizard):
    """Emits ``chain_calibrated(ChainCalibration)`` when finished; ``session``: a writable
    :class:`~snreg.session.Session` to store the chain in, or None. ``imu.snapshot()`` must give
    ``earth_from_imu`` (3, 3) and ``euler_deg``; ``make_source`` is called in the capture thread.
    ``tissue_source``: (make_source, imu) for the turn over tissue (default: the board's); ``probe``: the probe
    model, tracked in the tissue's pairs to leave it out (None: the robust fit alone does)."""

    chain_calibrated = Signal(object)

    def __init__(self, make_source: Callable[[], FrameSource], imu, calibration: StereoCalibration, board: Board, *,
                 session=None, tissue_source: tuple[Callable[[], FrameSource], object] | None = None,
                 probe: ProbeModel | None = None, parent=None):
        super().__init__(parent)
        self.setWindowTitle("Trocar calibration")
        self.choice: ChainChoice | None = None
        self._capture = LiveLoop(capture_samples, make_source, imu, calibration, board, parent=self)
        tissue_make_source, tissue_imu = tissue_source if tissue_source is not None else (make_source, imu)
        restarts = Restarts()
        self._tissue_capture = LiveLoop(capture_tissue_samples, tissue_make_source, tissue_imu, calibration, probe,
                                        restarts, parent=self)
        self.method_page, self.manual_page = MethodPage(), ManualPage()
        self.pivot_page, self.arc_page = PivotPage(self._capture), ArcPage(self._capture)
        self.tissue_page = TissuePage(self._tissue_capture, restarts)
        self.summary_page = SummaryPage(session)
        for page_id, page in ((PageId.METHOD, self.method_page), (PageId.PIVOT, self.pivot_page),
                              (PageId.TISSUE, self.tissue_page), (PageId.ARC, self.arc_page),
                              (PageId.MANUAL, self.manual_page), (PageId.SUMMARY, self.summary_page)):
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
        """Whether any of the wizard's threads (captures, fits, saving) is still running."""
        return (self._capture.running or self._tissue_capture.running or self.pivot_page.fitting
                or self.arc_page.fitting or self.tissue_page.fitting or self.summary_page.saving)

    def _feed_live_pages(self, page_id: int) -> None:
        """Run the feed of the live page now shown, and no other: the two may open the same cameras, so before one
        starts the other is waited for (at most the frame it is processing) until its source is closed."""
        page = self.page(page_id)
        wanted = page.capture if isinstance(page, LivePage) else None
        for capture in (self._capture, self._tissue_capture):
            if capture is wanted:
                continue
            if wanted is None:
                capture.stop()
            else:
                capture.shutdown()
        if wanted is not None:
            wanted.start()

    def _shut_down(self) -> None:
        """Close the sources and wait for every thread (on finish, cancel and close)."""
        self._capture.shutdown()
        self._tissue_capture.shutdown()
        for page in (self.pivot_page, self.arc_page, self.tissue_page, self.summary_page):
            page.shutdown()
