"""``snreg session verify``: read everything a session holds and name what is damaged, so nothing damaged is read back
silently.

What proves what: HDF5's Fletcher-32 checksum on every fixed-size dataset (a failed chunk fails its read); a SHA-256
per variable-length value (node ids, labels, snapshot JPEGs, events, id lists: their bytes live in HDF5's global heap,
which no filter covers); each closed video's size and SHA-256. What cannot be proved is said, not hidden: datasets
written without a checksum (files before format 3), a video never closed (the recording was killed), damaged journal
lines.

>>> report = verify("s.h5")
>>> report.ok, [d.to_json() for d in report.damaged], report.unproven
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import h5py
import numpy as np

from snreg.files import require_regular_file
from snreg.session.entries import EntryError, check_entry
from snreg.session.filecheck import read_checked
from snreg.session.journal import journal_path, read_journal
from snreg.session.reader import numbered_names, read_video
from snreg.session.schema import SessionError
from snreg.session.video import VideoSegment, count_frames, file_sha256
from snreg.session.writer import DIGESTED, row_digest

BLOCK_ROWS = 65536            # rows read at a time from a long stream table
_MAX_DEPTH = 16               # groups deeper than any session's (a damaged link could make a loop)
_FIELD_NAMES = {"left_jpeg": "left snapshot JPEG", "right_jpeg": "right snapshot JPEG"}


@dataclass(frozen=True)
class Damage:
    """One damaged thing: ``what`` (dataset, node, event, video, file), ``where`` (its name), ``why`` in words."""

    what: str
    where: str
    why: str

    def to_json(self) -> dict:
        return {"what": self.what, "where": self.where, "why": self.why}


@dataclass
class VerifyReport:
    """``damaged``: what failed its check; ``unproven``: what has no check to pass, in words; ``ok``: nothing damaged."""

    path: str
    damaged: list[Damage] = field(default_factory=list)
    unproven: list[str] = field(default_factory=list)
    videos: list[dict] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.damaged

    def to_json(self) -> dict:
        return {"ok": self.ok, "damaged": [d.to_json() for d in self.damaged], "unproven": self.unproven,
                "videos": self.videos}


def verify(path: str | Path, *, videos: bool = True) -> VerifyReport:
    """Check every dataset, every variable-length value's digest and (``videos``) every video file of a session.

    The HDF5 file is read in a child process first (:func:`.filecheck.read_checked`): damage that crashes libhdf5
    is reported as damage, with the objects a second walk of the file could not read, instead of ending the caller."""
    path = Path(path)
    report = VerifyReport(str(path))
    try:
        require_regular_file(path, "session", SessionError)
    except SessionError as err:
        report.damaged.append(Damage("file", str(path), str(err).removeprefix(f"{path}: ")))
        return report
    check, found = read_checked(path, _file_findings, defer=())
    if found is None and check.opens and not check.problems:     # a file this process records: read it here
        try:
            with h5py.File(path, "r") as h5:
                found = _file_findings(h5)
        except Exception as err:                                 # noqa: BLE001 - whatever the damage, a report
            found = [Damage("file", str(path), f"the HDF5 file cannot be read ({_short(err)})")], [], []
    if found is None:
        found = _walk_findings(path, check)
    damaged, unproven, segments = found
    report.damaged += damaged
    report.unproven += unproven
    for data in segments:
        segment = VideoSegment.from_json(data)
        for side in range(2):
            report.videos.append(_check_video(path, segment, side, report, hash_files=videos))
    bad_lines = read_journal(journal_path(path)).damaged
    if bad_lines:
        report.unproven.append(f"the journal has {bad_lines} damaged line{'s' if bad_lines > 1 else ''} (a kill "
                               "during a write leaves one torn line); they were skipped")
    return report


def _file_findings(h5: h5py.File) -> tuple[list[Damage], list[str], list[dict]]:
    """(damaged, unproven, video segments' JSON) of an open session file: what :func:`verify` reads of it."""
    report = VerifyReport(h5.filename)
    version = h5.attrs.get("format_version", 0)
    if not isinstance(version, (int, np.integer)) or version < 3:
        report.unproven.append(f"format {version}: written without checksums, so damage inside its datasets "
                               "cannot be detected")
    _check_datasets(h5, report)
    unreadable = {d.where for d in report.damaged}      # not read again: a damaged one can take seconds
    _check_node_digests(h5, report, unreadable)
    _check_event_digests(h5, report, unreadable)
    return report.damaged, report.unproven, _segments(h5, report)


def _segments(h5: h5py.File, report: VerifyReport) -> list[dict]:
    segments = []
    for name in numbered_names(h5["videos"]) if "videos" in h5 else []:
        try:
            segments.append(check_entry("video", read_video(h5["videos"][name])))
        except (EntryError, OSError, ValueError, KeyError, TypeError, RuntimeError) as err:
            report.damaged.append(Damage("video", f"videos/{name}", f"its record cannot be read ({err})"))
    return segments


def _walk_findings(path: Path, check) -> tuple[list[Damage], list[str], list[dict]]:
    """What a walk of a file that crashed (or stopped) the first reading child could not read, as damage; the
    video records when they read cleanly."""
    if not check.opens:
        return [Damage("file", str(path), f"the HDF5 file cannot be read ({check.why})")], [], []
    damaged, seen = [], set()
    for key, why in check.problems.items():              # keys: filecheck's module docstring
        what = "attribute" if "@" in key else "dataset" if "#" in key else "object"
        where = key if what == "attribute" else key.split("#")[0] or "/"
        if where not in seen:
            seen.add(where)
            damaged.append(Damage(what, where, why))
    segments = []
    if check.clean("/videos"):
        try:
            with h5py.File(path, "r") as h5:
                segments = _segments(h5, VerifyReport(str(path)))
        except OSError as err:
            damaged.append(Damage("file", str(path), f"the HDF5 file cannot be opened ({_short(err)})"))
    return damaged, [], segments


def _attributes(obj, report: VerifyReport) -> None:
    """Read every attribute of ``obj`` (a damaged one can crash libhdf5: :func:`verify` reads in a child)."""
    where = obj.name or "/"
    try:
        names = list(obj.attrs)
    except Exception as err:                        # noqa: BLE001
        report.damaged.append(Damage("attribute", f"{where}@*", f"its attributes cannot be listed ({_short(err)})"))
        return
    for name in names:
        try:
            obj.attrs[name]
        except Exception as err:                    # noqa: BLE001
            report.damaged.append(Damage("attribute", f"{where}@{name}", f"it cannot be read ({_short(err)})"))


def _datasets(group: h5py.Group, report: VerifyReport, depth: int = 0) -> list[h5py.Dataset]:
    """Every dataset under ``group`` (attributes read on the way); a member list or member that cannot be read is
    reported, the rest walked."""
    _attributes(group, report)
    try:
        names = list(group.keys())
    except Exception as err:                        # noqa: BLE001 - damage in a group costs that group
        report.damaged.append(Damage("group", group.name or "/", f"its members cannot be listed ({_short(err)})"))
        return []
    found = []
    for name in names:
        try:
            item = group[name]
        except Exception as err:                    # noqa: BLE001
            report.damaged.append(Damage("object", f"{group.name.rstrip('/')}/{name}", f"it cannot be opened "
                                                                                       f"({_short(err)})"))
            continue
        if isinstance(item, h5py.Dataset):
            _attributes(item, report)
            found.append(item)
        elif isinstance(item, h5py.Group) and depth < _MAX_DEPTH:
            found += _datasets(item, report, depth + 1)
    return found


def _check_datasets(h5: h5py.File, report: VerifyReport) -> None:
    unchecked, file_size = [], Path(h5.filename).stat().st_size
    for dataset in _datasets(h5, report):
        try:
            _check_dataset(dataset, file_size, report, unchecked)
        except Exception as err:                    # noqa: BLE001 - a damaged header: its dtype or shape fails
            report.damaged.append(Damage("dataset", dataset.name, f"it cannot be read ({_short(err)})"))
    if unchecked:
        report.unproven.append(f"{len(unchecked)} datasets were written without a Fletcher-32 checksum (e.g. "
                               f"{unchecked[0]})")


def _check_dataset(dataset: h5py.Dataset, file_size: int, report: VerifyReport, unchecked: list[str]) -> None:
    """Read one dataset whole (by blocks), its digest checked when it has one; damage goes into ``report``."""
    variable = h5py.check_dtype(vlen=dataset.dtype) is not None
    if variable and not _references_in_file(dataset, file_size):
        report.damaged.append(Damage("dataset", dataset.name, "a reference to its values points outside the file"))
        return
    try:
        for start in range(0, max(dataset.shape[0], 1) if dataset.shape else 1, BLOCK_ROWS):
            dataset[start:start + BLOCK_ROWS] if dataset.shape else dataset[()]
    except (OSError, ValueError, RuntimeError) as err:
        why = "its Fletcher-32 checksum failed" if "checksum" in str(err).lower() or "filter" in str(err).lower() \
            else f"it cannot be read ({_short(err)})"
        report.damaged.append(Damage("dataset", dataset.name, why))
        return
    if variable and "sha256" in dataset.attrs:
        values = [_text(v) for v in dataset[()]]
        if row_digest(values).decode("ascii") != _text(dataset.attrs["sha256"]):
            report.damaged.append(Damage("dataset", dataset.name, "its values differ from their SHA-256"))
    elif not variable and not dataset.fletcher32 and dataset.size:
        unchecked.append(dataset.name)


_REFERENCE = np.dtype([("length", "<u4"), ("address", "<u8"), ("index", "<u4")])   # HDF5's variable-length element


def _references_in_file(dataset: h5py.Dataset, file_size: int) -> bool:
    """Whether every stored variable-length element (length, global-heap address) lies within the file: a damaged
    one would make HDF5 read gigabytes before failing (20 s seen), so it is caught here unread."""
    if dataset.chunks is None or len(dataset.shape) != 1:
        return True
    for k in range(dataset.id.get_num_chunks()):
        info = dataset.id.get_chunk_info(k)
        if info.size != dataset.chunks[0] * _REFERENCE.itemsize:        # not the layout this check knows
            return True
        rows = min(dataset.chunks[0], dataset.shape[0] - info.chunk_offset[0])
        try:
            _, raw = dataset.id.read_direct_chunk(info.chunk_offset)
        except (OSError, ValueError, RuntimeError):
            return False
        refs = np.frombuffer(raw[:rows * _REFERENCE.itemsize], _REFERENCE)
        if np.any(refs["length"] > file_size) or np.any((refs["length"] > 0) & (refs["address"] >= file_size)):
            return False
    return True


def _check_node_digests(h5: h5py.File, report: VerifyReport, unreadable: set[str]) -> None:
    group = h5.get("nodes/intraop")
    if group is None or "digest" not in group or any(group[n].name in unreadable for n in (*DIGESTED, "digest")):
        return
    try:
        digests = group["digest"][()]
        columns = {name: group[name][()] for name in DIGESTED}
    except (OSError, ValueError, RuntimeError):
        return                                   # already reported as a dataset that cannot be read
    for k in range(len(digests)):
        node = _text(columns["id"][k]) if k < len(columns["id"]) else f"row {k}"
        for j, name in enumerate(DIGESTED):
            value = columns[name][k] if k < len(columns[name]) else None
            expected = bytes(digests[k][j])
            if not expected:
                continue                          # a row written before digests (a resumed older file)
            if value is None or row_digest([_bytes(value)]) != expected:
                report.damaged.append(Damage("node", f"nodes/intraop row {k} ({node})",
                                             f"its {_FIELD_NAMES.get(name, name)} differs from its SHA-256"))


def _check_event_digests(h5: h5py.File, report: VerifyReport, unreadable: set[str]) -> None:
    if "events_digest" not in h5 or "events" not in h5 or {"/events", "/events_digest"} & unreadable:
        return
    try:
        events, digests = h5["events"][()], h5["events_digest"][()]
    except (OSError, ValueError, RuntimeError):
        return
    if len(digests) != len(events):
        report.damaged.append(Damage("dataset", "/events", f"{len(events)} events but {len(digests)} digests"))
    for k, (event, digest) in enumerate(zip(events, digests)):
        if row_digest([_text(event)]) != bytes(digest):
            report.damaged.append(Damage("event", f"events row {k}", "its text differs from its SHA-256"))


def _check_video(path: Path, segment: VideoSegment, side: int, report: VerifyReport, *, hash_files: bool) -> dict:
    """One recorded file: present, and (closed) its size and SHA-256 as stored; a JSON summary of it."""
    video = segment.path(path, side)
    where = str(video)
    summary = {"side": ("left", "right")[side], "path": where, "codec": segment.codec, "closed": segment.closed,
               "frames": segment.frames[side] if segment.closed else None}
    if not video.exists():
        report.damaged.append(Damage("video", where, "the file is missing"))
        return summary
    if not segment.closed:
        summary["frames"] = count_frames(video)
        report.unproven.append(f"{video.name} was never closed (the recording was killed): it has no size or SHA-256 "
                               f"on record; {summary['frames']} frames are readable")
        return summary
    size = video.stat().st_size
    if size != segment.size[side]:
        report.damaged.append(Damage("video", where, f"it is {size} bytes, {segment.size[side]} were recorded"))
    elif hash_files and file_sha256(video) != segment.sha256[side]:
        report.damaged.append(Damage("video", where, "its SHA-256 differs from the one recorded when it was closed"))
    return summary


def _short(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 160 else text[:157] + "..."


def _text(value) -> str:
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else str(value)


def _bytes(value) -> bytes:
    if isinstance(value, str):
        return value.encode("utf-8")
    return bytes(value) if not isinstance(value, np.ndarray) else value.tobytes()
