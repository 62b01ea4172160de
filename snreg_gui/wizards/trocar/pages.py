"""The trocar wizard's still pages: the method, manual entry of the distances, and the summary that saves the chain.

Why: these pages only take the technician's choice and values and show the result; the values are checked
by :class:`~snreg.chain.ChainCalibration` itself, and a bad one is named in one sentence that blocks Next.
The summary stores the chain in the session in a :class:`~snreg_gui.common.workers.Worker` (the journal is fsynced).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from PySide6.QtWidgets import QButtonGroup, QFormLayout, QLabel, QLineEdit, QRadioButton, QVBoxLayout, QWizardPage

from snreg.chain import THESIS_IMU_TROCAR_MM, THESIS_TROCAR_CAMERA_MM, ChainCalibration
from snreg.geometry import euler_from_rotation
from snreg_gui.common.workers import Worker, release_finished


class PageId(enum.IntEnum):
    """The pages; the summary is the last (a page with none after it is the wizard's final one)."""

    METHOD = 0
    PIVOT = 1
    TISSUE = 2
    ARC = 3
    MANUAL = 4
    SUMMARY = 5


@dataclass(frozen=True, eq=False)
class ChainChoice:
    """The chain a page settled on, its ``method`` ("pivot", "tissue", "arc" or "manual") and one line on its
    quality."""

    chain: ChainCalibration
    method: str
    quality: str


class MethodPage(QWizardPage):
    """Pivot calibration over a board (recommended) or over tissue, the thesis's arc method, or distances measured
    by hand."""

    def __init__(self):
        super().__init__()
        self.setTitle("Trocar calibration: method")
        self.setSubTitle("How to find the trocar-camera distance and the IMU-camera axes of the chain.")
        self.pivot_button = QRadioButton("Pivot calibration (recommended): pivot the endoscope in the trocar in front "
                                         "of a still checkerboard; gives the distance and the IMU-camera rotation")
        self.tissue_button = QRadioButton("Turn the camera over tissue (no board): the distance and the IMU-camera "
                                          "rotation from the camera's own motion in the stereo video")
        self.arc_button = QRadioButton("Arc method (thesis eq. 14): the distance from the swings of the camera; "
                                       "IMU axes aligned by eye")
        self.manual_button = QRadioButton("Manual entry: distances measured by hand (thesis: 460 mm and 158 mm)")
        self._group = QButtonGroup(self)
        layout = QVBoxLayout(self)
        for page_id, button in ((PageId.PIVOT, self.pivot_button), (PageId.TISSUE, self.tissue_button),
                                (PageId.ARC, self.arc_button), (PageId.MANUAL, self.manual_button)):
            self._group.addButton(button, page_id)
            layout.addWidget(button)
        self.pivot_button.setChecked(True)

    def nextId(self) -> int:
        return self._group.checkedId()


class ManualPage(QWizardPage):
    """The IMU-trocar and trocar-camera distances in mm (thesis §4.1 defaults), checked as they are typed."""

    def __init__(self):
        super().__init__()
        self.setTitle("Trocar calibration: manual entry")
        self.setSubTitle("Distances along the shaft, measured by hand; the IMU axes are taken as aligned with the "
                         "camera's, as in the thesis.")
        self.imu_trocar_edit = QLineEdit(f"{THESIS_IMU_TROCAR_MM:g}")
        self.trocar_camera_edit = QLineEdit(f"{THESIS_TROCAR_CAMERA_MM:g}")
        self.problem = QLabel("")
        self.problem.setWordWrap(True)
        form = QFormLayout(self)
        form.setFieldGrowthPolicy(QFormLayout.FieldGrowthPolicy.FieldsStayAtSizeHint)   # numbers, not screen-wide bars
        form.addRow("IMU-trocar distance (mm)", self.imu_trocar_edit)
        form.addRow("trocar-camera distance (mm)", self.trocar_camera_edit)
        form.addRow(self.problem)
        self.chain: ChainCalibration | None = None
        for edit in (self.imu_trocar_edit, self.trocar_camera_edit):
            edit.textChanged.connect(self._check)
        self._check()

    def _check(self) -> None:
        self.chain, problem = None, ""
        imu_trocar = _millimetres(self.imu_trocar_edit.text())
        trocar_camera = _millimetres(self.trocar_camera_edit.text())
        if imu_trocar is None:
            problem = _ask_for_number("IMU-trocar", THESIS_IMU_TROCAR_MM)
        elif trocar_camera is None:
            problem = _ask_for_number("trocar-camera", THESIS_TROCAR_CAMERA_MM)
        else:
            try:
                self.chain = ChainCalibration.manual(imu_trocar, trocar_camera)
            except ValueError as err:
                problem = f"Check the distances: {err}."
        self.problem.setText(problem)
        self.completeChanged.emit()

    def isComplete(self) -> bool:
        return self.chain is not None

    def validatePage(self) -> bool:
        if self.chain is None:
            return False
        self.wizard().set_choice(ChainChoice(self.chain, "manual", "distances measured by hand; IMU-camera axes "
                                                                   "aligned by eye (identity)"))
        return True

    def nextId(self) -> int:
        return PageId.SUMMARY


def _ask_for_number(distance: str, example_mm: float) -> str:
    return f"Enter the {distance} distance as a number of millimetres, such as {example_mm:g}."


def _millimetres(text: str) -> float | None:
    """A finite number typed with a decimal point or comma, else None."""
    try:
        value = float(text.strip().replace(",", "."))
    except ValueError:
        return None
    return value if math.isfinite(value) else None


class SummaryPage(QWizardPage):
    """The chain (distances, rotation in degrees, quality); Finish saves it into the session, if there is one."""

    def __init__(self, session=None):
        super().__init__()
        self.setTitle("Trocar calibration: summary")
        self._session = session
        self._saver: Worker | None = None
        self._saved = False
        self.method, self.distances, self.rotation, self.quality = QLabel(""), QLabel(""), QLabel(""), QLabel("")
        destination = (f"Finish saves the chain into the session {session.path}." if session is not None
                       else "No session is open: Finish passes the chain on without saving it.")
        self.destination, self.status = QLabel(destination), QLabel("")
        layout = QVBoxLayout(self)
        for label in (self.method, self.distances, self.rotation, self.quality, self.destination, self.status):
            label.setWordWrap(True)
            layout.addWidget(label)
        layout.addStretch(1)

    @property
    def saving(self) -> bool:
        return self._saver is not None

    def initializePage(self) -> None:
        choice = self.wizard().choice
        chain = choice.chain
        self._saved = False
        yaw, pitch, roll = euler_from_rotation(chain.imu_from_camera)
        self.method.setText(f"method: {choice.method}")
        self.distances.setText(f"trocar-camera distance {chain.trocar_camera_mm:.2f} mm; IMU-trocar distance "
                               f"{chain.imu_trocar_mm:.2f} mm (it cancels out of the chain)")
        self.rotation.setText(f"IMU-camera rotation (imu_from_camera; yaw, pitch, roll): {yaw:.2f}, {pitch:.2f}, "
                              f"{roll:.2f} degrees")
        self.quality.setText(choice.quality)
        self.status.setText("")

    def validatePage(self) -> bool:
        """True once saved (or with no session); otherwise starts saving and Finish completes when it is done."""
        if self._session is None or self._saved:
            return True
        if self._saver is None:
            self.status.setText("saving...")
            saver = Worker(self._session.set_calibration, chain=self.wizard().choice.chain)
            saver.returned.connect(self._save_done)
            saver.errored.connect(self._save_failed)
            saver.finished.connect(self._saver_finished)
            self._saver = saver.start()
        return False

    def shutdown(self) -> None:
        """Wait for a save in progress (closing the wizard)."""
        if self._saver is not None:
            self._saver.wait()
            self._saver = None

    def _save_done(self, _) -> None:
        self._saved = True
        self.status.setText("saved")
        self.wizard().accept()

    def _save_failed(self, message: str) -> None:
        self.status.setText(f"The chain was not saved ({message}); check the session file and press Finish again.")

    def _saver_finished(self) -> None:
        if release_finished(self._saver, self.sender()):
            self._saver = None
