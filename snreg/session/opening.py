"""Opening a session for reading, whatever state it is in: the front half of :meth:`snreg.session.Session.open`.

Why here: what a session file holds decides what may be read of it. The files must be regular files (a pipe or a
device would block or never end); the journal's entries are checked field by field (:mod:`.entries`); the HDF5
file is read first by a child process (:mod:`.filecheck`), so a crash of libhdf5 on damaged metadata becomes
"damaged" instead of the end of the program; and the root attributes are read one by one, so a damaged ``format``
or a missing ``case_id`` costs that attribute, not the streams behind it. A file without the ``format`` attribute
is taken for a session when it has a session's groups.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import h5py

from snreg.files import require_regular_file
from snreg.session.entries import checked_entries
from snreg.session.filecheck import FileCheck, read_checked, walk_chunk_index
from snreg.session.journal import journal_path, read_journal
from snreg.session.reader import HEADER_KEYS
from snreg.session.salvage import FileParts, read_parts, stream_problem
from snreg.session.schema import FORMAT, FORMAT_VERSION, STREAM_DTYPES, SessionError

__all__ = ["Opened", "open_parts", "regular_file"]

_SESSION_GROUPS = ("streams", "nodes", "calibration", "registration")
_PLAUSIBLE_VERSION = 1000       # a format_version beyond this is a damaged attribute, not a newer snreg
_RECOVER = "run 'snreg session recover'"
_PARTS = ("/@", "/nodes", "/calibration", "/registration", "/events", "/streams")   # reported part by part (.salvage)


@dataclass
class Opened:
    """What :func:`open_parts` found: the header, the HDF5 file when it can be read (``check`` says what of it), the
    journal's good entries, whether a journal exists, and one sentence per problem (file and journal)."""

    header: dict
    h5: h5py.File | None
    check: FileCheck | None
    entries: list
    journal: bool
    damaged: bool
    problems: list[str] = field(default_factory=list)
    parts: FileParts | None = None           # the file's parts as read by the checking child, when it read them whole


def regular_file(path: Path, what: str) -> bool:
    """True when ``path`` is a regular file we may read, False when it does not exist; :class:`SessionError` for
    anything else (a folder, a device or pipe, no permission)."""
    if not path.exists() and not path.is_symlink():
        return False
    require_regular_file(path, what, SessionError)
    if not os.access(path, os.R_OK):
        raise SessionError(f"{path}: no permission to read the {what}")
    return True


def open_parts(path: Path) -> Opened:
    """Check ``path`` and its journal and open what can be read; :class:`SessionError` when nothing can."""
    exists = regular_file(path, "session")
    journal = read_journal(journal_path(path))
    entries, problems = checked_entries(journal.entries, journal.lines)
    if journal.damaged:
        problems.append(f"journal: {journal.damaged} damaged line(s) skipped")
    journal_header = next((data for kind, data in entries if kind == "session"), None)
    has_journal = bool(journal.entries) or journal.damaged > 0
    if not exists and not entries:
        raise SessionError(f"{path}: no such session file")
    check, parts = read_checked(path, _read_whole) if exists else (None, None)
    if check is not None and not check.opens:
        if journal_header is None:
            raise SessionError(_unreadable(path, check.why))
        problems.append(f"the HDF5 file cannot be read: {check.why}")
    if check is None or not check.opens:
        if not exists:
            problems.append("the HDF5 file is missing; everything shown comes from the journal")
        return Opened(dict(journal_header or {}), None, check, entries, has_journal, True, problems)
    try:
        h5 = h5py.File(path, "r")
    except OSError as err:
        if journal_header is None or "unable to lock" in str(err):
            raise SessionError(_unreadable(path, check.why or _open_error(err))) from None
        problems.append(f"the HDF5 file cannot be opened: {_open_error(err)}")
        return Opened(dict(journal_header), None, check, entries, has_journal, True, problems)
    try:
        header, header_problems = _header(h5, check, journal_header, path)
    except BaseException:
        h5.close()
        raise
    if header is None:                      # not a session, but the journal says one was begun: read the journal
        h5.close()
        problems.append("the HDF5 file holds no snreg session; everything shown comes from the journal")
        return Opened(dict(journal_header), None, check, entries, has_journal, True, problems)
    problems += header_problems + [_problem(key, why) for key, why in check.problems.items()
                                   if not key.startswith(_PARTS)]
    return Opened(header, h5, check, entries, has_journal, bool(check.problems or header_problems), problems, parts)


def _read_whole(h5: h5py.File) -> FileParts | None:
    """All that opening a session reads of its file, run in a child (:func:`.filecheck.read_checked`): the root
    attributes, every part, each stream's table and chunk index. None, so that the file is walked to find the damage,
    when anything is amiss."""
    for key in list(h5.attrs):
        h5.attrs[key]
    parts = read_parts(h5, None)
    if parts.problems or any(stream_problem(h5, name, None) for name in STREAM_DTYPES):
        return None
    for name in STREAM_DTYPES:
        if f"streams/{name}" in h5:                 # a stream newer than the file's format may be absent
            walk_chunk_index(h5[f"streams/{name}"])
    return parts


def _header(h5: h5py.File, check: FileCheck, journal_header: dict | None, path: Path):
    """(header, problems), or (None, []) for an HDF5 file that is not a session while a journal exists; raises
    :class:`SessionError` for a foreign file without a journal and for a newer format."""
    values, problems = {}, []
    for key in HEADER_KEYS:
        if not check.attribute_ok("/", key):
            if "/@*" not in check.problems and f"/@{key}" not in check.problems:
                continue                                            # simply absent
            why = check.problems.get(f"/@{key}") or check.problems.get("/@*", "")
            problems.append(f"the root attribute {key} is damaged ({why})")
            continue
        try:
            if key in h5.attrs:
                values[key] = _plain(h5.attrs[key])
        except (OSError, ValueError, KeyError, RuntimeError, TypeError) as err:
            problems.append(f"the root attribute {key} cannot be read ({err})")
    version = values.get("format_version")
    if version is not None and (isinstance(version, bool) or not isinstance(version, int)):
        problems.append(f"the root attribute format_version is {version!r}, not a whole number")
        values.pop("format_version")
    elif version is not None and version > FORMAT_VERSION:
        journal_version = (journal_header or {}).get("format_version")
        if journal_version is not None and journal_version <= FORMAT_VERSION or version > _PLAUSIBLE_VERSION:
            problems.append(f"the root attribute format_version is {version}, not a version of this file"
                            + (f" (its journal says {journal_version})" if journal_version is not None else ""))
            values.pop("format_version")
        else:
            raise SessionError(f"{path}: session format version {version} is newer than this snreg reads "
                               f"({FORMAT_VERSION}); update snreg")
    if values.get("format") != FORMAT:
        looks = sum(name in h5 for name in _SESSION_GROUPS if check.clean_path(f"/{name}")) >= 2
        if not looks:
            if journal_header is not None:
                return None, []
            raise SessionError(f"{path}: not a snreg session (the HDF5 file lacks format={FORMAT!r} and a session's "
                               "groups)")
        if "format" in values:
            problems.append(f"the root attribute format is {values['format']!r}, not {FORMAT!r}")
        elif not any("format" in p for p in problems):
            problems.append("the root attribute format is missing")
        values["format"] = FORMAT
    for key, value in list(values.items()):
        if key not in ("format_version",) and not isinstance(value, str):
            problems.append(f"the root attribute {key} is {value!r}, not text")
            values.pop(key)
    header = {**(journal_header or {}), **values} if not problems else {**values, **(journal_header or {})}
    header.setdefault("format", FORMAT)
    if not header.get("case_id"):
        problems.append("the root attribute case_id is missing")
    for key in ("case_id", "created_utc", "snreg_version"):
        header.setdefault(key, "")
    header.setdefault("format_version", FORMAT_VERSION if journal_header is None else
                      journal_header.get("format_version", FORMAT_VERSION))
    return header, problems


def _plain(value):
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return value.item() if hasattr(value, "item") and getattr(value, "size", 2) == 1 else value


def _problem(key: str, why: str) -> str:
    return f"{key.lstrip('/') or 'the file'}: {why}"


def _open_error(err: OSError) -> str:
    text = " ".join(str(err).split())
    if "unable to lock" in text:
        return "it is open for writing in another program (being recorded?)"
    return text


def _unreadable(path: Path, why: str) -> str:
    if "open for writing" in why:
        return f"{path}: {why}; wait until it is closed, or read a copy"
    if "permission" in why:
        return f"{path}: {why}"
    if "not an HDF5 file" in why:
        return f"{path}: not a readable snreg session file ({why}), and no journal beside it"
    return (f"{path}: not a readable snreg session file ({why}), and no journal beside it; if it was being recorded, "
            f"{_RECOVER} on it to save what is left")
