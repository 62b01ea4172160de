"""The demo's preoperative side: the phantom's SPECT written beside the session and loaded into the registration
panel, with the operator's nominal set-up rotation already in the initial alignment.

Why: in ``snreg-gui --demo`` the operator should meet the real preop path (NM DICOM read, segmented with the
threshold slider) and only have to store the nodes and register (the alignment starts from the centroids).
"""

from __future__ import annotations

import numpy as np

from snreg import geometry
from snreg.demo.headless import spect_path_for
from snreg.demo.phantom import NOMINAL_TILT_DEG, setup_patient_from_trocar
from snreg_gui.common.workers import Worker


class DemoSpect:
    """Writes the SPECT in a worker, then loads it into ``window.registration`` and sets the nominal rotation."""

    def __init__(self, window):
        self._window = window
        rig = window.rig
        self.path = spect_path_for(window.session.path)
        self.worker = Worker(rig.write_phantom_spect, self.path)
        self.worker.returned.connect(self._written)
        self.worker.errored.connect(lambda message: window.statusBar().showMessage(f"demo SPECT not written: {message}"))
        self.worker.start()

    def _written(self, path) -> None:
        panel = self._window.registration
        panel.load_preop(str(path))
        rotation = geometry.invert(setup_patient_from_trocar(NOMINAL_TILT_DEG))[:3, :3]
        panel.alignment.set_values(geometry.euler_from_rotation(rotation), np.zeros(3))
