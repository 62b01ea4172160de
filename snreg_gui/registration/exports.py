"""The registration panel's exports and final mark: which registration the exports write (the one marked final in
the session, else the result shown while it answers the inputs), the file dialogs, the export workers with their
busy dialog, and marking a stored registration final.

Why apart: :class:`~snreg_gui.registration.panel.RegistrationPanel` runs registrations and shows them; this part
decides what leaves the app as a file. It is a mixin of the panel and uses the panel's widgets (``export_buttons``,
``final_label``, ``stored``) and state (``_session``, ``_record``, ``_record_current``, ``_exporting``, ``_tasks``).
"""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import QFileDialog, QMessageBox, QProgressDialog

from snreg.workflow.registration_run import EXPORTS, RunRecord, export_file, final_record, report_context
from snreg_gui.common import file_places
from snreg_gui.common.workers import sentence

# what each export's suggested file name ends in, after <case>_<method>_ (snreg_gui.common.file_places.export_name)
EXPORT_NAMES = {"pairs": "pairs.csv", "slicer": "preop_in_trocar.mrk.json", "report": "report.png"}


class PanelExports:
    """Exports and the final mark of the registration panel (module docstring)."""

    def refresh_stored(self) -> None:
        """Re-read the session's stored registrations and final mark into the list; the exports follow the mark."""
        session = self._session
        self.stored.show_stored([] if session is None else session.registrations(),
                                writable=session is not None and session.writable)
        self._update_exports()

    def _set_exports_enabled(self, enabled: bool) -> None:
        for button in self.export_buttons.values():
            button.setEnabled(enabled)

    def _export_record(self) -> tuple[RunRecord | None, str]:
        """What the exports write, and why: the registration marked final in the session when there is one, else
        the result shown while it answers the current inputs; (None, the reason) when neither can be exported."""
        if self._session is not None and self._session.final_registration() is not None:
            try:
                record = final_record(self._session)
            except ValueError as err:
                return None, sentence(str(err))
            return record, f"Exports write registration {record.final_n}, marked final."
        if self._record is None or not self._record_current:
            return None, "Run a registration with the current inputs before exporting."
        return self._record, "No registration is marked final: exports write the result shown."

    def _update_exports(self) -> None:
        record, why = self._export_record()
        self._set_exports_enabled(record is not None and self._exporting == 0)
        self.final_label.setText(why if self._session is not None and (record is not None or
                                                                       self._session.final_registration() is not None)
                                 else "")

    def _mark_final(self, n) -> None:
        """Mark registration ``n`` final in the session (None: unmark), in a worker (journal fsync)."""
        if self._session is None or not self._session.writable:
            return self._say("Only a session being recorded can be marked here; use the Review tab for a saved one.")
        self._tasks.start(self._session.set_final_registration, n,
                          returned=lambda _: self._final_marked(n), errored=self._say_problem)

    def _final_marked(self, n) -> None:
        self.refresh_stored()
        self._say("No registration is marked final now." if n is None else
                  f"Registration {n} is marked final in the session; the exports use it.")

    def export_start(self, kind: str) -> str:
        """Where the export dialog of ``kind`` starts: the session's folder (or the last one used) and a suggested
        name ``<case>_<method>_<what>`` for what the exports write."""
        case = self._session.case_id if self._session is not None else ""
        record, _ = self._export_record()
        method = record.result.method if record is not None else self.method_combo.currentText()
        return file_places.start_path(self._session, file_places.export_name(case, method, EXPORT_NAMES[kind]))

    def _choose_export(self, kind: str) -> None:
        record, why = self._export_record()
        if record is None:
            return self._say(why)
        name, file_filter, _ = EXPORTS[kind]
        path, _ = QFileDialog.getSaveFileName(self, f"Export {name}", self.export_start(kind), file_filter)
        if path:
            file_places.remember(path)
            self.export(kind, path)

    def export(self, kind: str, path: str) -> None:
        """Write what the exports write (:meth:`_export_record`) as ``kind`` (a key of ``EXPORTS``) to ``path`` in a
        worker, with a busy dialog; the report carries the session's case, file and calibration
        (:func:`report_context`)."""
        record, why = self._export_record()
        if record is None:
            return self._say(why)
        self._exporting += 1
        self._set_exports_enabled(False)
        context = report_context(self._session) if kind == "report" else None
        self._show_export_progress(f"Writing the {EXPORTS[kind][0]} to {path} ...")
        self._tasks.start(export_file, kind, path, record, context,
                          returned=lambda written: self._exported(written, record), errored=self._export_failed)

    def _show_export_progress(self, text: str) -> None:
        if self.export_progress is None:
            dialog = QProgressDialog(self)
            dialog.setWindowTitle("Exporting")
            dialog.setRange(0, 0)                     # busy: a figure's rendering reports no steps
            dialog.setCancelButton(None)             # a file half-written is never left, but it cannot be stopped
            dialog.setWindowModality(Qt.WindowModality.NonModal)
            dialog.setAutoClose(False)
            dialog.setAutoReset(False)
            self.export_progress = dialog
        self.export_progress.setLabelText(text)
        self.export_progress.show()

    def _export_ended(self) -> None:
        self._exporting -= 1
        if self._exporting == 0:
            if self.export_progress is not None:
                self.export_progress.hide()
            self._update_exports()

    def _exported(self, path, record: RunRecord) -> None:
        self._export_ended()
        which = "" if record.final_n is None else f" (registration {record.final_n}, marked final)"
        extra = "; its facts also in the .json beside it" if str(path).lower().endswith(".png") else ""
        self._say(f"Written {path}{which}{extra}.")

    def _export_failed(self, message: str) -> None:
        self._export_ended()
        self._say_problem(message)
        box = QMessageBox(QMessageBox.Icon.Warning, "Export failed", sentence(message), parent=self)
        self.export_problem = box
        box.open()
