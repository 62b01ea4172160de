"""The demo's preoperative side: the phantom's SPECT written beside the session and loaded into the registration
panel, nothing typed.

Why: in ``snreg-gui --demo`` the operator should meet the real preop path (NM DICOM read, segmented with the
threshold slider) and only have to store the nodes and press Run. As in a real case the start comes from gravity
(:mod:`snreg_gui.registration.start`): the SPECT says the patient lay supine (Patient Position HFS), the simulated
table is tilted 27 degrees head down (:data:`snreg.demo.phantom.TABLE_TILT_DEG`) while the panel assumes snreg's
default 30, and the IMU gives down in the trocar frame. No angle is pre-filled from the simulator's truth.
"""

from __future__ import annotations

from snreg.demo.headless import spect_path_for
from snreg_gui.common.workers import Worker


class DemoSpect:
    """Writes the SPECT in a worker, then loads it into ``window.registration``."""

    def __init__(self, window):
        self._window = window
        rig = window.rig
        self.path = spect_path_for(window.session.path)
        self.worker = Worker(rig.write_phantom_spect, self.path)
        self.worker.returned.connect(self._written)
        self.worker.errored.connect(lambda message: window.statusBar().showMessage(f"demo SPECT not written: {message}"))
        self.worker.start()

    def _written(self, path) -> None:
        self._window.registration.load_preop(str(path))
