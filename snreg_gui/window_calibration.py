"""What the main window does when a wizard applies a calibration: track or map with it from now on, store it in the
session, say so in words, and when stored nodes were measured with another calibration, offer to re-express them
(:mod:`snreg.workflow.chain_change`; the session keeps their old values on record). The chain just replaced goes
with the offer: a node stored with the camera's insertion tracked keeps the slide tracked since that chain's distance.

A mixin of :class:`snreg_gui.app.MainWindow`: it uses the window's ``rig``, ``session``, ``acquisition`` and status
bar.
"""

from __future__ import annotations

from PySide6.QtWidgets import QMessageBox

from snreg.session import SessionError
from snreg.workflow.chain_change import calibration_change, id_list, reexpress


class CalibrationApplying:
    """Applying a stereo or trocar calibration, and the re-expression offer (module docstring)."""

    def apply_stereo_calibration(self, calibration, saved_to=None) -> None:
        """Track with ``calibration`` from now on and store it in the session; say in words where it was saved
        (``saved_to``, the wizard's file) and that it is applied; stored nodes: say so, offer to re-express them."""
        previous, self.rig.calibration = self.rig.calibration, calibration
        stored = self.session is not None and self.session.writable
        if stored:
            self.session.set_calibration(stereo=calibration)
        places = [f"saved to {saved_to}"] if saved_to else []
        places += [f"stored in the session {self.session.path.name}"] if stored else []
        applied = (f"The stereo calibration (RMS {calibration.rms_reprojection_px:.3f} px, baseline "
                   f"{calibration.baseline_mm:.2f} mm) is {' and '.join(places + ['applied'])}: tracking uses it "
                   "from now on.")
        self._calibration_applied(applied, previous, self.rig.chain)

    def apply_chain(self, chain) -> None:
        """Map the tip through ``chain`` from now on (the trocar wizard has stored it in the session); say so in
        words; stored nodes: say so, offer to re-express them."""
        previous, self.rig.chain = self.rig.chain, chain
        stored = self.session is not None and self.session.writable
        where = (f"saved in the session {self.session.path} and applied" if stored else
                 "applied (not saved: no session is open)")
        applied = (f"The trocar calibration (trocar-camera {chain.trocar_camera_mm:.1f} mm) is {where}: stored "
                   "positions use it from now on.")
        self._calibration_applied(applied, self.rig.calibration, previous)

    def _calibration_applied(self, applied: str, previous_stereo, previous_chain) -> None:
        """Say ``applied`` in the status bar and in a box (:attr:`calibration_notice`), or, when stored nodes were
        mapped with another calibration, in the box that offers to re-express them (:attr:`calibration_prompt`)."""
        self.statusBar().showMessage(applied)
        if self._offer_reexpression(previous_stereo, previous_chain, applied):
            return
        box = QMessageBox(QMessageBox.Icon.Information, "Calibration applied", applied, parent=self)
        box.finished.connect(lambda _: setattr(self, "calibration_notice", None))
        self.calibration_notice = box
        box.open()

    def _offer_reexpression(self, previous_stereo, previous_chain, applied: str = "") -> bool:
        """When stored nodes were mapped with another calibration than the rig's now: say so plainly and offer to
        re-express them (the session keeps their old values on record); True when the box is shown."""
        session = self.session
        if session is None or not session.writable:
            return False
        change = calibration_change(session, self.rig.calibration, self.rig.chain, previous_stereo=previous_stereo,
                                    previous_chain=previous_chain)
        if change is None:
            return False
        box = QMessageBox(QMessageBox.Icon.Warning, "Calibration changed: stored nodes", change.message, parent=self)
        informative = [applied] if applied else []
        if change.question:
            box.setInformativeText("\n\n".join(informative + [change.question]))
            box.addButton(f"Re-express {id_list(change.movable)}", QMessageBox.ButtonRole.AcceptRole)
            box.addButton("Keep them as stored", QMessageBox.ButtonRole.RejectRole)
        else:
            box.setInformativeText(applied)
            box.addButton(QMessageBox.StandardButton.Ok)
        offered = bool(change.question)
        box.finished.connect(lambda _: self._reexpression_answered(box, previous_stereo, previous_chain, offered))
        self.calibration_prompt = box
        box.open()
        return True

    def _reexpression_answered(self, box: QMessageBox, previous_stereo, previous_chain, offered: bool) -> None:
        """``offered``: the box asked (Re-express / Keep); an OK on a box that only told re-expresses nothing."""
        self.calibration_prompt = None
        role = box.buttonRole(box.clickedButton()) if box.clickedButton() is not None else None
        if not offered or role != QMessageBox.ButtonRole.AcceptRole or self.session is None:
            self.statusBar().showMessage("stored nodes kept as measured: a registration will say it mixes calibrations")
            return
        try:
            moved = reexpress(self.session, self.rig.calibration, self.rig.chain, previous_stereo=previous_stereo,
                              previous_chain=previous_chain)
        except (SessionError, OSError) as err:
            self.statusBar().showMessage(f"The nodes could not be re-expressed: {err}")
            return
        if self.acquisition is not None:
            self.acquisition.set_nodes(self.session.intraop_records())
        self._nodes_changed()
        self.statusBar().showMessage(f"re-expressed {id_list(moved)} under the new calibration; their old positions "
                                     "stay on record in the session")
