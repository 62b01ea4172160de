"""The demo's preoperative side: the phantom's SPECT and its report of stations written beside the session and loaded
into the registration panel, nothing typed.

Why: in ``snreg-gui --demo`` the operator should meet the real preop path (NM DICOM read, segmented with the
threshold slider, the hot spots labelled with the report's stations: "EXT L") and only have to store the nodes and
press Run. The files are those ``snreg demo --headless`` writes (:func:`snreg.demo.phantom_preop.write_phantom_preop`),
so both demos ask the registration the same question. As in a real case the start comes from gravity
(:mod:`snreg_gui.registration.start`): the SPECT says the patient lay supine (Patient Position HFS), the simulated
table is tilted 27 degrees head down (:data:`snreg.demo.phantom.TABLE_TILT_DEG`) while the panel assumes snreg's
default 30, and the IMU gives down in the trocar frame. No angle is pre-filled from the simulator's truth.
"""

from __future__ import annotations

from snreg.demo.phantom_preop import PhantomPreop, spect_path_for, write_phantom_preop
from snreg_gui.common.workers import Worker


class DemoSpect:
    """Writes the SPECT and its station table in a worker, then loads both into ``window.registration``'s preop box."""

    def __init__(self, window):
        self._window = window
        self.path = spect_path_for(window.session.path)
        self.worker = Worker(write_phantom_preop, window.rig, window.session.path)
        self.worker.returned.connect(self._written)
        self.worker.errored.connect(lambda message: window.statusBar().showMessage(f"demo SPECT not written: {message}"))
        self.worker.start()

    def _written(self, written: PhantomPreop) -> None:
        self._window.registration.preop_box.load(written.spect_path, stations=written.stations_path)
