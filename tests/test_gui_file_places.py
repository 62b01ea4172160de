"""Where file dialogs and wizards start and the names they suggest (snreg_gui.common.file_places): pure functions."""

import datetime
from pathlib import Path

from snreg_gui.common import file_places
from snreg_gui.common.file_places import calibration_name, calibration_path, dialog_start, export_name, start_folder

NOON = datetime.datetime(2024, 5, 2, 12, 30, 5, tzinfo=datetime.timezone.utc)


def test_dialogs_start_in_the_sessions_folder_else_the_last_folder_else_home(tmp_path):
    session = tmp_path / "cases" / "phantom-01.h5"
    last = tmp_path / "last"
    last.mkdir()
    assert start_folder(session, str(last)) == (tmp_path / "cases").resolve()
    assert start_folder(None, str(last)) == last
    assert start_folder(None, str(tmp_path / "gone")) == Path.home()         # a folder deleted since is skipped
    assert start_folder(None, None) == Path.home()
    assert dialog_start(session, None, "x_pairs.csv") == str((tmp_path / "cases").resolve() / "x_pairs.csv")
    assert dialog_start(None, str(last)) == str(last)


def test_suggested_names_say_case_method_and_what_and_are_safe_file_names():
    assert export_name("phantom-01", "global", "pairs.csv") == "phantom-01_global_pairs.csv"
    assert export_name("", "icp", "report.png") == "no-case_icp_report.png"
    assert export_name("a/b c", "cpd", "report.png") == "a-b-c_cpd_report.png"
    assert calibration_name("/data/phantom-01.h5", "stereo", NOON) == "phantom-01_stereo_20240502-123005.yaml"
    assert calibration_name(None, "stereo", NOON) == "calibration_stereo_20240502-123005.yaml"


def test_wizards_save_next_to_the_session_else_in_the_last_folder_else_home_snreg(tmp_path):
    session = tmp_path / "cases" / "phantom-01.h5"
    assert calibration_path(session, None, "stereo", NOON) == \
        (tmp_path / "cases").resolve() / "phantom-01_stereo_20240502-123005.yaml"
    assert calibration_path(None, str(tmp_path), "stereo", NOON).parent == tmp_path
    assert calibration_path(None, None, "stereo", NOON).parent == Path.home() / file_places.DEFAULT_FOLDER_NAME


def test_the_folder_chosen_last_is_remembered(tmp_path):
    chosen = tmp_path / "exports"
    chosen.mkdir()
    file_places.remember(chosen / "a.csv")
    assert file_places.start_path(None) == str(chosen)
    assert file_places.start_path(None, "b.csv") == str(chosen / "b.csv")


def test_an_open_dialog_starts_at_the_start_path_and_remembers_what_was_chosen(tmp_path, monkeypatch):
    from PySide6.QtWidgets import QFileDialog

    first, chosen = tmp_path / "first", tmp_path / "nodes"
    first.mkdir()
    chosen.mkdir()
    file_places.remember(first / "x.csv")
    asked = []

    def dialog(parent, title, start, file_filter, answer):
        asked.append((title, start, file_filter))
        return answer, ""

    monkeypatch.setattr(QFileDialog, "getOpenFileName", lambda *a: dialog(*a, answer=""))
    assert file_places.choose_file(None, "Node file", None, "Node files (*.csv)") == ""      # cancelled
    assert file_places.start_path(None) == str(first)                                      # nothing remembered
    monkeypatch.setattr(QFileDialog, "getOpenFileName", lambda *a: dialog(*a, answer=str(chosen / "n.csv")))
    assert file_places.choose_file(None, "Node file", None, "Node files (*.csv)") == str(chosen / "n.csv")
    assert asked == [("Node file", str(first), "Node files (*.csv)")] * 2
    assert file_places.start_path(None) == str(chosen)
