"""The write-ahead journal beside a session (``<session>.h5.journal``): what makes a stored node durable.

HDF5 cannot promise a consistent file after a kill in the middle of a write, so every node, calibration,
preop set and registration is first appended here as one JSON line prefixed by its CRC-32 and fsynced;
a torn or damaged line (the kill's last, partial write) fails its checksum and is skipped on reading.
"""

from __future__ import annotations

import json
import os
import tempfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from snreg.errors import SessionError
from snreg.files import require_regular_file
from snreg.session.schema import JOURNAL_SUFFIX


def journal_path(session_path: str | Path) -> Path:
    session_path = Path(session_path)
    return session_path.with_name(session_path.name + JOURNAL_SUFFIX)


@dataclass(frozen=True)
class JournalEntries:
    """The readable entries, in order, as (kind, data) pairs, how many lines were damaged, and the line number of each
    entry (for messages)."""

    entries: list
    damaged: int
    lines: list = field(default_factory=list)


def fsync_directory(path: str | Path) -> None:
    """Make the names in ``path`` (a folder) durable: a new or renamed file survives a crash under its name."""
    directory = os.open(path, os.O_RDONLY)
    try:
        os.fsync(directory)
    finally:
        os.close(directory)


def _line(kind: str, data: dict) -> bytes:
    payload = json.dumps({"kind": kind, "data": data}, separators=(",", ":"), allow_nan=True).encode("utf-8")
    return b"%08x " % zlib.crc32(payload) + payload + b"\n"


class Journal:
    """An append-only journal; :meth:`append` returns once the line is on disk (fsync)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._file = open(self.path, "ab")
        fsync_directory(self.path.parent)

    @classmethod
    def start(cls, path: str | Path, kind: str, data: dict) -> "Journal":
        """A new journal whose first line is already on disk: written under a temporary name of its own, then linked
        to ``path``, so a kill at any moment leaves either no journal or one that begins with this entry, and of two
        processes starting the same journal one gets :class:`SessionError` (the link never replaces a journal)."""
        path = Path(path)
        handle, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".creating", dir=path.parent)
        partial = Path(name)
        try:
            with open(handle, "wb") as file:
                file.write(_line(kind, data))
                file.flush()
                os.fsync(file.fileno())
            try:
                os.link(partial, path)
            except FileExistsError:
                raise SessionError(f"{path}: a journal already exists there (another session by that name is "
                                   "being recorded?); choose a new file name") from None
            except OSError:                             # no hard links on this file system: claim the name first
                if path.exists():
                    raise SessionError(f"{path}: a journal already exists there; choose a new file name") from None
                os.replace(partial, path)
        finally:
            partial.unlink(missing_ok=True)
        return cls(path)

    def append(self, kind: str, data: dict) -> None:
        self._file.write(_line(kind, data))
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        self._file.close()


def read_journal(path: str | Path) -> JournalEntries:
    """Every line whose checksum holds; a missing journal has no entries. :class:`SessionError` when the journal is not
    a regular file (a folder, a device, a pipe) or cannot be read."""
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        return JournalEntries([], 0)
    require_regular_file(path, "session journal", SessionError)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise SessionError(f"{path}: cannot read the session journal ({err.strerror or err})") from None
    entries, damaged, lines = [], 0, []
    for number, line in enumerate(raw.split(b"\n"), start=1):
        if not line:
            continue
        crc, _, payload = line.partition(b" ")
        try:
            if int(crc, 16) != zlib.crc32(payload):
                raise ValueError
            record = json.loads(payload)
            entries.append((str(record["kind"]), record["data"]))
            lines.append(number)
        except (ValueError, KeyError, TypeError, RecursionError):
            damaged += 1
    return JournalEntries(entries, damaged, lines)
