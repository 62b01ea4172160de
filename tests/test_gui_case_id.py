"""The new-session dialog refuses a case id that looks like a name or a date as it is typed, and says why."""

import pytest

from snreg_gui.common.case_id_dialog import HINT, CaseIdDialog


@pytest.fixture
def dialog(qtbot):
    widget = CaseIdDialog()
    qtbot.addWidget(widget)
    return widget


def test_empty_id_cannot_be_accepted(dialog):
    assert not dialog.ok_button.isEnabled() and dialog.reason.text() == HINT


@pytest.mark.parametrize("typed, why", [("Smith 12/03/1960", "no spaces"), ("Smith1960", "year of birth"),
                                        ("1960-03-12", "date"), ("pt-12.03.1960", "date")])
def test_a_name_or_date_is_refused_beside_the_field_as_typed(qtbot, dialog, typed, why):
    qtbot.keyClicks(dialog.field, typed)
    assert dialog.reason.text().startswith("Refused: ") and why in dialog.reason.text()
    assert not dialog.ok_button.isEnabled()
    dialog.field.clear()
    qtbot.keyClicks(dialog.field, "phantom-01")
    assert dialog.ok_button.isEnabled() and dialog.reason.text() == HINT and dialog.case_id() == "phantom-01"
