"""The new-session dialog: a pseudonymous case id, checked as it is typed.

Why: "Smith 12/03/1960" was accepted up to the save dialog and then refused only in the status bar. The dialog
asks :func:`snreg.session.schema.validate_case_id` (the rule the session file itself enforces) at every key,
says why an id is refused right under the field, and keeps OK disabled until the id is accepted.

>>> dialog = CaseIdDialog(parent)
>>> if dialog.exec(): case_id = dialog.case_id()
"""

from __future__ import annotations

from PySide6.QtWidgets import QDialog, QDialogButtonBox, QFormLayout, QLabel, QLineEdit

from snreg.errors import SessionError
from snreg.session.schema import validate_case_id

HINT = "letters, digits, '.', '_' or '-'; no patient names or dates (e.g. phantom-01)"


class CaseIdDialog(QDialog):
    """A case id field, the reason it is refused beside it, and OK/Cancel (OK only for an accepted id)."""

    def __init__(self, parent=None):
        super().__init__(parent)
        self.setWindowTitle("New session")
        self.field = QLineEdit()
        self.field.setPlaceholderText("phantom-01")
        self.reason = QLabel(HINT)
        self.reason.setWordWrap(True)
        self.buttons = QDialogButtonBox(QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel)
        form = QFormLayout(self)
        form.addRow("Pseudonymous case id", self.field)
        form.addRow("", self.reason)
        form.addRow(self.buttons)
        self.field.textChanged.connect(self._check)
        self.buttons.accepted.connect(self.accept)
        self.buttons.rejected.connect(self.reject)
        self._check("")

    @property
    def ok_button(self):
        return self.buttons.button(QDialogButtonBox.StandardButton.Ok)

    def case_id(self) -> str:
        return self.field.text()

    def _check(self, text: str) -> None:
        refusal = ""
        if text:
            try:
                validate_case_id(text)
            except SessionError as err:
                refusal = str(err).split(" is refused: ", 1)[-1]      # the reason, without repeating the id
        self.reason.setText(f"Refused: {refusal}" if refusal else HINT)
        self.reason.setStyleSheet("color: #b00020; font-weight: bold" if refusal else "")
        self.ok_button.setEnabled(bool(text) and not refusal)
