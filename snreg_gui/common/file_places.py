"""Where file dialogs and wizards start, and the names they suggest.

Why: a technician exporting a pairing table or saving a calibration expects it beside the session being
recorded, not in whatever folder the app was started from, and a suggested name that says what the file is
(``phantom-01_global_pairs.csv``). Dialogs start in the session's folder; with no session, in the folder last
chosen in any dialog (remembered in the app's settings); failing that, in the home folder. The pure functions
(:func:`start_folder`, :func:`dialog_start`, :func:`export_name`, :func:`calibration_name`) decide; the two
Qt-facing ones (:func:`start_path`, :func:`remember`, :func:`choose_file`) read and write the remembered folder.

>>> QFileDialog.getSaveFileName(self, "Export", start_path(session, export_name(case, "global", "pairs.csv")))
>>> remember(chosen_path)
"""

from __future__ import annotations

import datetime
import re
from pathlib import Path

from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QFileDialog

LAST_FOLDER_KEY = "files/last_folder"
DEFAULT_FOLDER_NAME = "snreg"          # under the home folder: where wizards save when there is no session


def start_folder(session_path, last_folder) -> Path:
    """The session's folder if there is a session, else ``last_folder`` if it still exists, else the home folder."""
    if session_path:
        return Path(session_path).expanduser().resolve().parent
    if last_folder and Path(last_folder).is_dir():
        return Path(last_folder)
    return Path.home()


def dialog_start(session_path, last_folder, name: str = "") -> str:
    """What to pass a file dialog as its start: :func:`start_folder`, with ``name`` in it when one is suggested."""
    folder = start_folder(session_path, last_folder)
    return str(folder / name) if name else str(folder)


def _safe(text: str) -> str:
    """``text`` usable in a file name on any system (separators and reserved characters become ``-``)."""
    return re.sub(r"[^\w.+-]+", "-", text.strip()).strip("-.") or "snreg"


def export_name(case_id: str, method: str, what: str) -> str:
    """``<case>_<method>_<what>``, e.g. ``phantom-01_global_pairs.csv`` (``what`` carries the ending)."""
    return "_".join(_safe(part) for part in (case_id or "no-case", method) if part) + f"_{what}"


def calibration_name(session_path, kind: str, now: datetime.datetime | None = None) -> str:
    """A calibration file name that sorts by time and never overwrites an earlier one:
    ``<session stem>_<kind>_<UTC yyyymmdd-hhmmss>.yaml`` (``calibration`` instead of the stem without a session)."""
    now = now or datetime.datetime.now(datetime.timezone.utc)
    stem = _safe(Path(session_path).stem) if session_path else "calibration"
    return f"{stem}_{kind}_{now.strftime('%Y%m%d-%H%M%S')}.yaml"


def calibration_path(session_path, last_folder, kind: str, now: datetime.datetime | None = None) -> Path:
    """Where a wizard saves a calibration by default: next to the session; without one, in the last folder chosen
    or ``~/snreg`` (created when saved)."""
    folder = (start_folder(session_path, None) if session_path else
              Path(last_folder) if last_folder and Path(last_folder).is_dir() else Path.home() / DEFAULT_FOLDER_NAME)
    return folder / calibration_name(session_path, kind, now)


def _session_path(session) -> str | None:
    return None if session is None else str(session.path)


def _settings() -> QSettings:
    return QSettings("snreg", "snreg")        # the app's own settings (snreg_gui.app)


def last_folder() -> str | None:
    value = _settings().value(LAST_FOLDER_KEY)
    return str(value) if value else None


def start_path(session, name: str = "") -> str:
    """:func:`dialog_start` for ``session`` (a :class:`~snreg.session.Session` or None) and the remembered folder."""
    return dialog_start(_session_path(session), last_folder(), name)


def choose_file(parent, title: str, session, file_filter: str) -> str:
    """An existing file chosen in an open dialog starting at :func:`start_path` (its folder remembered); "" when the
    user cancels."""
    path, _ = QFileDialog.getOpenFileName(parent, title, start_path(session), file_filter)
    remember(path)
    return path


def remember(path) -> None:
    """Remember the folder of a path chosen in a dialog (a folder chosen is remembered itself)."""
    if not path:
        return
    path = Path(path)
    _settings().setValue(LAST_FOLDER_KEY, str(path if path.is_dir() else path.parent))
