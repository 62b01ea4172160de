"""Opening the device dialog and the calibration wizards from the main window, and applying what they return.

Why: a wizard needs the cameras to itself, so acquisition pauses while it runs and starts again after, with
the new calibration or chain. The rig gives each wizard its feed (:meth:`~snreg.rig.protocols.Rig.board_source`,
:meth:`~snreg.rig.protocols.Rig.pivot_source`, :meth:`~snreg.rig.protocols.Rig.tissue_source`): rendered scenes on
the demo rig, the cameras and IMU on the hardware one. The code after the sources is the same.
"""

from __future__ import annotations

import json

from snreg.calibration.checkerboard import THESIS_BOARD
from snreg_gui.common import file_places

_DEVICES_KEY = "devices/config"
WIZARD_SIZE = (1200, 800)        # live feeds and tables need room


class WizardLauncher:
    """Owned by the main window; ``window`` gives ``rig``, ``session``, ``settings``, ``set_rig``, pausing and
    restarting acquisition, applying a calibration, and the status bar."""

    def __init__(self, window):
        self._window = window
        self.active = None          # the wizard or dialog now open

    def stereo(self) -> None:
        from snreg_gui.wizards.stereo.wizard import StereoCalibrationWizard
        window = self._window
        if not self._have_rig():
            return
        session_path = None if window.session is None else window.session.path
        wizard = StereoCalibrationWizard(window.rig.board_source, THESIS_BOARD, parent=window,
                                         save_path=file_places.calibration_path(session_path, file_places.last_folder(),
                                                                                "stereo"))
        wizard.calibrated.connect(lambda calibration: window.apply_stereo_calibration(calibration, wizard.saved_path))
        self._open(wizard)

    def trocar(self) -> None:
        from snreg_gui.wizards.trocar.wizard import TrocarWizard
        window = self._window
        if not self._have_rig():
            return
        make_source, imu = window.rig.pivot_source()
        wizard = TrocarWizard(make_source, imu, window.rig.calibration, THESIS_BOARD, session=window.session,
                              tissue_source=window.rig.tissue_source(), probe=window.rig.probe, parent=window)
        wizard.chain_calibrated.connect(window.apply_chain)
        self._open(wizard)

    def select_devices(self) -> None:
        from snreg.rig import HardwareRig, RigConfig
        from snreg_gui.wizards.device_dialog import DeviceDialog
        window = self._window
        stored = window.settings.value(_DEVICES_KEY)
        try:
            config = RigConfig.from_dict(json.loads(stored)) if stored else None
        except (ValueError, TypeError):
            config = None
        dialog = DeviceDialog(config, parent=window)
        if not dialog.exec():
            return
        config = dialog.config()
        if config.mode == "replay":
            window.settings.setValue(_DEVICES_KEY, json.dumps(config.to_dict()))
            window.replay(config.left, config.speed)
            return
        try:
            chain = window.session.calibration().get("chain") if window.session is not None else None
            rig = HardwareRig(config, chain=chain)
        except (ValueError, OSError) as err:
            window.statusBar().showMessage(f"The devices could not be opened: {err}")
            return
        window.settings.setValue(_DEVICES_KEY, json.dumps(config.to_dict()))
        window.set_rig(rig)

    def shutdown(self) -> None:
        if self.active is not None:
            self.active.reject()
            self.active = None

    # -- helpers -------------------------------------------------------------
    def _have_rig(self) -> bool:
        if self._window.rig is None:
            self._window.statusBar().showMessage("Choose the cameras first: Devices > Select cameras and IMU...")
            return False
        return True

    def _open(self, wizard) -> None:
        """Stop acquisition (the wizard needs the cameras), show the wizard, restart acquisition when it closes."""
        self._window.pause_acquisition()
        self.active = wizard
        wizard.finished.connect(self._closed)
        room = self._window.screen().availableGeometry()           # never larger than the screen (1024 x 700)
        wizard.resize(min(max(wizard.width(), WIZARD_SIZE[0]), room.width()),
                      min(max(wizard.height(), WIZARD_SIZE[1]), room.height()))
        wizard.open()

    def _closed(self, _result: int) -> None:
        self.active = None
        self._window.restart_acquisition()
