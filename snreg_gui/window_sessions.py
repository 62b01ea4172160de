"""The main window's session actions (File menu): a new session, continuing one after a restart, replaying a
recorded one, opening one for review and the recent-files list; how the review tab is wired to the window.

A mixin of :class:`snreg_gui.app.MainWindow`: it uses the window's ``session``, ``rig``, ``recent``, ``review``,
``tabs`` and status bar, and its ``set_session``/``set_rig``.
"""

from __future__ import annotations

import time
from pathlib import Path

from PySide6.QtWidgets import QFileDialog

from snreg.session import Session, SessionError
from snreg_gui.common import file_places
from snreg_gui.common.case_id_dialog import CaseIdDialog


class SessionActions:
    """New, continue, replay, review and recent sessions (module docstring)."""

    def _fill_recent(self) -> None:
        self.recent_menu.clear()
        for path in self.recent.paths():
            self.recent_menu.addAction(path).triggered.connect(lambda _=False, p=path: self.open_for_review(p))
        if self.recent_menu.isEmpty():
            self.recent_menu.addAction("(none)").setEnabled(False)

    def new_session(self) -> None:
        dialog = CaseIdDialog(self)
        if not dialog.exec():
            return
        case_id = dialog.case_id()
        path, _ = QFileDialog.getSaveFileName(self, "New session file", file_places.start_path(self.session,
                                              f"{case_id}.h5"), "snreg sessions (*.h5)")
        if path:
            file_places.remember(path)
            self.set_session(self._create(path, case_id))

    def continue_session(self, path: str | None = None) -> None:
        """Reopen a session to record more nodes into it (after a restart or a crash)."""
        path = path or file_places.choose_file(self, "Continue session", self.session, "snreg sessions (*.h5)")
        if not path:
            return
        file_places.remember(path)
        try:
            session = Session.resume(path)
        except SessionError as err:
            self.statusBar().showMessage(str(err))
            return
        self.set_session(session)

    def replay(self, path, speed: float = 1.0) -> None:
        """Acquire from the recorded session ``path`` (its video and IMU at ``speed`` times its pace) into a new
        session beside it, named ``<name>-replay-<time>.h5``."""
        from snreg.demo.replay import ReplayRig
        try:
            rig = ReplayRig(path, speed=speed)
        except (SessionError, OSError, ValueError) as err:
            self.statusBar().showMessage(f"Cannot replay {path}: {err}")
            return
        with Session.open(path) as source:
            case_id = f"{source.case_id}-replay"[:64]
        target = Path(path).with_name(f"{Path(path).stem}-replay-{time.strftime('%Y%m%d-%H%M%S')}.h5")
        self.set_rig(rig)
        self.set_session(self._create(target, case_id))
        self.statusBar().showMessage(f"replaying {Path(path).name} at {speed:g}x into {target.name}")

    def _wire_review(self) -> None:
        """The review tab: a final mark goes through the session being recorded when it is the file shown; it follows
        that session (read again after each store and registration); the session it read of a saved file feeds the
        Registration tab when none is recorded (its preop nodes, down, landmarks and registrations, read-only)."""
        self.review.recording_session = lambda: self.session
        self.review.final_changed.connect(lambda _: self.registration.refresh_stored())
        self.review.failed.connect(self.statusBar().showMessage)
        self.review.loaded.connect(self._review_loaded)
        self.review.session_read.connect(self._reviewed_session_read)
        self.registration.registered.connect(lambda _: self.review.live_changed())

    def _review_loaded(self, path: str) -> None:
        if not self.review.following:            # the session being recorded keeps saying so in the status bar
            self.statusBar().showMessage(f"reviewing {path}")

    def _reviewed_session_read(self, session) -> None:
        """A session read for review (closed, read-only) to the Registration tab, unless one is being recorded."""
        if self.session is None:
            self.registration.set_session(session)

    def choose_review(self) -> None:
        path = file_places.choose_file(self, "Open session for review", self.session, "snreg sessions (*.h5)")
        if path:
            self.open_for_review(path)

    def open_for_review(self, path: str | Path) -> None:
        self.recent.add(path)
        self.review.load(str(path))
        self.tabs.setCurrentWidget(self.review)
        self._update_title()

    def _create(self, path, case_id: str) -> Session | None:
        try:
            session = Session.create(path, case_id=case_id)
        except (SessionError, OSError) as err:
            self.statusBar().showMessage(str(err))
            return None
        if self.rig is not None:
            session.set_calibration(stereo=self.rig.calibration, chain=self.rig.chain)
        return session
