"""The main window's title and the question on close: both name the session file, in full.

Why: the demo records into a file the technician did not choose (the temp folder), and a session ended by mistake in
surgery is lost time, so the window always says where it records (title and status bar: the full path) and closing
while recording asks first, naming what is stored and where ("4 nodes and 3 landmarks stored, all saved in
/path/x.h5; end the session?").

A mixin of :class:`snreg_gui.app.MainWindow`: it uses the window's ``session``, ``rig``, ``review``, ``tabs``,
``demo``, ``close_prompt`` and ``_end_confirmed``, and its ``shutdown``.
"""

from __future__ import annotations

from pathlib import Path

from PySide6.QtWidgets import QApplication, QMessageBox

from snreg import __version__
from snreg.landmarks import LANDMARK


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


def end_question(nodes: int, landmarks: int, path) -> str:
    """The question on close: what is stored (nodes and landmarks) and where it is saved."""
    return f"{_count(nodes, 'node')} and {_count(landmarks, 'landmark')} stored, all saved in {path}; end the session?"


class WindowClosing:
    """Window title, status line and the question on close (module docstring)."""

    def _update_title(self) -> None:
        """The window says what it records into (demo and the session file's full path) and which file the review
        tab shows."""
        reviewed = Path(self.review.path).name if self.review.path and not self.review.following else ""
        recording = str(self.session.path) if self.session is not None else ""
        mode = self.rig.description.split(":")[0] if self.demo else ""
        parts = [f"snreg {__version__}", mode, recording, f"reviewing {reviewed}" if reviewed else ""]
        if not (mode or recording or reviewed):
            parts.append("no session")
        self.setWindowTitle(" - ".join(part for part in parts if part))
        self.tabs.setTabText(self.tabs.indexOf(self.review), f"Review: {reviewed}" if reviewed else "Review")

    def closeEvent(self, event) -> None:
        """While recording, ask first (:attr:`close_prompt`); the window closes when the technician says yes."""
        if self._recording() and not self._end_confirmed:
            event.ignore()
            self._ask_to_end()
            return
        self.shutdown()
        super().closeEvent(event)

    def quit_without_asking(self) -> None:
        """End the app now, without the question on close (Ctrl-C, a kill signal, the bench): Qt 6's quit closes
        the windows first, and a close the question holds back would cancel the quit."""
        self._end_confirmed = True
        QApplication.instance().quit()

    def _recording(self) -> bool:
        return self.session is not None and self.session.writable and self.rig is not None

    def _ask_to_end(self) -> None:
        if self.close_prompt is not None:
            return
        text = end_question(len(self.session.intraop_records()), len(self.session.intraop_records(kind=LANDMARK)),
                            self.session.path)
        box = QMessageBox(QMessageBox.Icon.Question, "End the session?", text, parent=self)
        end = box.addButton("End the session", QMessageBox.ButtonRole.AcceptRole)
        box.setDefaultButton(box.addButton("Keep recording", QMessageBox.ButtonRole.RejectRole))
        box.finished.connect(lambda _: self._end_answered(box.clickedButton() is end))
        self.close_prompt = box
        box.open()

    def _end_answered(self, end: bool) -> None:
        self.close_prompt = None
        if end:
            self._end_confirmed = True
            self.close()
