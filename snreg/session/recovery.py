"""``snreg session recover``: rebuild a clean session file from a damaged one and its journal, losing nothing readable.

What is kept: everything :meth:`Session.open` can read (the journal for what it holds: nodes and their versions,
registrations, calibrations, the preop set, events; the HDF5 file for the rest and for every stream row outside
damaged chunks, whatever the root attributes say). Recovering in place takes an exclusive lock beside the file (a
second recover is refused in words, naming the first), writes the clean file under a temporary name, checks that
it holds every row it should, then keeps the damaged file under a name never used before
(``<name>.damaged-<UTC time>[-k]``, made by a hard link, so no backup is ever overwritten) and renames the clean
file into place. :class:`Recovery` says what came from where.
"""

from __future__ import annotations

import datetime
import fcntl
import os
import re
import shutil
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import h5py

from snreg.files import atomic_write
from snreg.landmarks import LANDMARK
from snreg.session import Session, salvage
from snreg.session.entries import checked_entries
from snreg.session.journal import journal_path, read_journal
from snreg.session.schema import STREAM_DTYPES, SessionError
from snreg.session.video import segment_files

__all__ = ["Recovery", "recover", "RecoverLock"]

_MAX_GROWN_BYTES = 1 << 40        # a file cut short is grown back (sparse) to its recorded length up to this


@dataclass(frozen=True)
class Recovery:
    """What a recover wrote (``path``), where the damaged file was kept (``backup``, None when written elsewhere),
    and what it holds: per part a count and its source ("journal", "file", "journal and file")."""

    path: Path
    backup: Path | None
    journal: bool
    nodes: tuple[int, str]
    registrations: tuple[int, str]
    calibration: tuple[tuple[str, str], ...]
    preop: int
    events: int
    streams: dict[str, int]
    videos: int = 0
    problems: list[str] = field(default_factory=list)
    carried: list[str] = field(default_factory=list)      # video files linked (or copied) beside a copy elsewhere
    landmarks: tuple[int, str] = (0, "")                  # intraop landmarks, as ``nodes``

    def lines(self) -> list[str]:
        """The report in words, one line each."""
        def part(count: int, what: str, source: str) -> str:
            return f"{count} {what}" + (f" from the {source}" if count and source else "")

        lines = [f"recovered session written to {self.path}"
                 + (f"; the damaged file is kept as {self.backup}" if self.backup else "")]
        lines.append("salvaged: " + "; ".join([
            part(self.nodes[0], "node(s)", self.nodes[1]), part(self.registrations[0], "registration(s)",
                                                                self.registrations[1]),
            *([part(self.landmarks[0], "landmark(s)", self.landmarks[1])] if self.landmarks[0] else []),
            f"{self.preop} preop node(s)", f"{self.events} event(s)"]))
        lines.append("streams from the file: " + ", ".join(f"{name} {n}" for name, n in self.streams.items())
                     + " rows")
        calibration = ", ".join(f"{kind} (from the {source})" for kind, source in self.calibration)
        lines.append(f"calibration: {calibration or 'none readable'}")
        if self.carried:
            lines.append(f"videos: {self.videos} segment(s) on record; beside the recovered file: "
                         + ", ".join(self.carried))
        elif self.videos:
            lines.append(f"videos: {self.videos} segment(s) on record, their files beside the session as they are")
        if not self.journal:
            lines.append("there was no journal beside the file: only what the HDF5 file still held could be saved")
        lines += [f"could not be read: {problem}" for problem in self.problems]
        return lines


class RecoverLock:
    """An exclusive lock on ``.<name>.recover-lock`` beside a session (``flock``: released when the process ends, even
    by a kill); a second taker gets :class:`SessionError` naming the holder (process, host, start time)."""

    def __init__(self, path: Path):
        self.path = path.with_name(f".{path.name}.recover-lock")
        self._fd: int | None = None

    def __enter__(self) -> "RecoverLock":
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.read(fd, 300).decode("utf-8", "replace").strip() or "another process"
                os.close(fd)
                raise SessionError(f"{self.path.with_name(self.path.name[1:-len('.recover-lock')])}: another recover "
                                   f"is working on it ({holder}); wait until it has finished") from None
            try:
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino   # not a lock file a finished recover removed
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        started = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
        os.ftruncate(fd, 0)
        os.write(fd, f"process {os.getpid()} on {socket.gethostname()}, started {started}".encode())
        self._fd = fd
        return self

    def __exit__(self, *exc) -> None:
        if self._fd is not None:
            try:
                os.unlink(self.path)
            except FileNotFoundError:
                pass
            os.close(self._fd)          # closing releases the lock, after the name is gone
            self._fd = None


def recover(path: str | Path, out: str | Path | None = None) -> Recovery:
    """Rebuild a clean session from ``path`` and its journal into ``out`` (default: in place, module docstring)."""
    path = Path(path)
    target = Path(out) if out is not None else path
    in_place = target == path or (target.exists() and path.exists() and target.resolve() == path.resolve())
    if in_place:
        with RecoverLock(path):
            return _recover(path, path, in_place=True)
    return _recover(path, target, in_place=False)


def _recover(path: Path, target: Path, in_place: bool) -> Recovery:
    with tempfile.TemporaryDirectory(prefix=f".{path.name}.recovering-", dir=path.parent) as work:
        session = _open(path, Path(work))
        with session:
            return _write(session, path, target, in_place)


def _open(path: Path, work: Path) -> Session:
    """The session at ``path``; a file cut short (a copy stopped half way, a full disk) is read from a copy grown back
    to its recorded length with zeros, so what lies before the cut is read."""
    try:
        session = Session.open(path)
        cut = _cut_short(" ".join(session.problems)) if session._h5 is None else None
    except SessionError as err:
        cut = _cut_short(str(err))
        if cut is None:
            raise
        session = None
    if cut is None:
        return session
    if session is not None:
        session.close()
    copy = work / path.name
    shutil.copyfile(path, copy)
    os.truncate(copy, cut[1])
    if journal_path(path).exists():
        shutil.copyfile(journal_path(path), journal_path(copy))
    grown = Session.open(copy)
    grown.problems.insert(0, f"the file was cut short at {cut[0]} of its {cut[1]} bytes; what lies before the cut "
                             "was read")
    return grown


def _cut_short(text: str) -> tuple[int, int] | None:
    """(length, recorded length) from libhdf5's message about a truncated file, None for any other message."""
    match = re.search(r"truncated file: eof = (\d+).*?stored_eof = (\d+)", text)
    if not match:
        return None
    eof, stored = int(match[1]), int(match[2])
    return (eof, stored) if eof < stored <= _MAX_GROWN_BYTES else None


def _write(session: Session, path: Path, target: Path, in_place: bool) -> Recovery:
    journal = read_journal(journal_path(session.path))
    entries, _ = checked_entries(journal.entries, journal.lines)
    expected = {name: int(len(session.stream(name))) for name in STREAM_DTYPES}
    report = _report(session, entries)
    carried = [] if in_place else _carry_videos(session, path, target)
    with atomic_write(target) as temporary:
        session.save_as(temporary)
        written = _stream_rows(temporary)
        short = [name for name in STREAM_DTYPES if written.get(name, 0) < expected[name]]
        if short:
            raise SessionError(f"{path}: the recovered file would hold fewer {', '.join(short)} rows than were "
                               "readable; nothing was replaced")
        backup = _keep_damaged(path) if in_place and path.exists() else None
    rows = [problem for name in STREAM_DTYPES                  # what reading the rows found (after the open)
            if (problem := salvage.stream_problem(session._h5, name, session._check)) not in (None, *session.problems)]
    return Recovery(target, backup, session.has_journal, report["nodes"], report["registrations"],
                    report["calibration"], report["preop"], report["events"], written, len(session.videos()),
                    list(session.problems) + rows, carried, report["landmarks"])


def _carry_videos(session: Session, path: Path, target: Path) -> list[str]:
    """A recovered copy written elsewhere names its video files after itself (:func:`.video.segment_files`) and
    finds them beside it: each file there is a hard link to the original (a copy across file systems). The
    segments' records are renamed; the names carried, in words. A file of that name already there is refused."""
    plans = []
    for n, data in sorted(session._videos.items()):
        names = segment_files(target, n)
        for old, new in zip(data["files"], names):
            source, destination = path.with_name(old), target.with_name(new)
            if source.exists() and source.resolve() != destination.resolve():
                if destination.exists():
                    raise SessionError(f"{destination}: already exists; the recovered session's video would go there "
                                       "(move it away, or recover into another folder)")
                plans.append((source, destination))
        session._videos[n] = {**data, "files": list(names)}
    for source, destination in plans:
        try:
            os.link(source, destination)
        except OSError:
            shutil.copyfile(source, destination)
    return [destination.name for _, destination in plans]


def _report(session: Session, entries: list) -> dict:
    """Counts of what the session holds and where each part came from."""
    node_ids = {data["id"] for kind, data in entries if kind == "node"}
    nodes, landmarks = session.intraop_records(), session.intraop_records(LANDMARK)
    in_journal = sum(node.id in node_ids for node in nodes)
    marks_in_journal = sum(node.id in node_ids for node in landmarks)
    registration_ns = {data["n"] for kind, data in entries if kind == "registration"}
    registrations = session.registrations()
    from_journal = sum(r.n in registration_ns for r in registrations)
    calibration_kinds = {data["kind"] for kind, data in entries if kind == "calibration"}
    preop = session.preop_nodes()
    return {"nodes": (len(nodes), _source(in_journal, len(nodes) - in_journal)),
            "landmarks": (len(landmarks), _source(marks_in_journal, len(landmarks) - marks_in_journal)),
            "registrations": (len(registrations), _source(from_journal, len(registrations) - from_journal)),
            "calibration": tuple((kind, "journal" if kind in calibration_kinds else "file")
                                 for kind in sorted(session.calibration())),
            "preop": 0 if preop is None else len(preop), "events": len(session.events())}


def _source(journal: int, file: int) -> str:
    if journal and file:
        return f"journal ({journal}) and the file ({file})"
    return "journal" if journal else ("file" if file else "")


def _stream_rows(path: Path) -> dict[str, int]:
    with h5py.File(path, "r") as h5:
        return {name: int(h5[f"streams/{name}"].shape[0]) for name in STREAM_DTYPES}


def _keep_damaged(path: Path) -> Path:
    """A new name for the damaged file beside it, never one that exists (a hard link: the file itself stays put until
    the clean one is renamed over its name)."""
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    for k in range(1, 10_000):
        backup = path.with_name(f"{path.name}.damaged-{stamp}" + (f"-{k}" if k > 1 else ""))
        try:
            os.link(path, backup)
            return backup
        except FileExistsError:
            continue
        except OSError:                          # no hard links here: a copy, made under a name no one has
            try:
                with open(path, "rb") as source, open(backup, "xb") as copy:
                    shutil.copyfileobj(source, copy)
                    copy.flush()
                    os.fsync(copy.fileno())
                return backup
            except FileExistsError:
                continue
    raise SessionError(f"{path}: no free name to keep the damaged file beside it; tidy the folder and try again")
