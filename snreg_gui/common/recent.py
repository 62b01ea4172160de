"""Recently used session files, remembered across runs in QSettings (most recent first)."""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import QSettings

MAX_RECENT = 8
_KEY = "sessions/recent"


class RecentSessions:
    """The last ``MAX_RECENT`` session paths; files that no longer exist are left out when listed."""

    def __init__(self, settings: QSettings):
        self._settings = settings

    def paths(self) -> list[str]:
        stored = self._settings.value(_KEY, []) or []
        stored = [stored] if isinstance(stored, str) else list(stored)
        return [p for p in stored if Path(p).exists()]

    def add(self, path) -> None:
        path = str(Path(path).resolve())
        self._settings.setValue(_KEY, ([path] + [p for p in self.paths() if p != path])[:MAX_RECENT])
