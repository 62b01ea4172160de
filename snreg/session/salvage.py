"""Reading what is still readable of a session's HDF5 file, part by part, after :mod:`.filecheck` has read it safely.

Why: a damaged file should cost what is damaged and no more. A part (nodes, calibration, preop, registrations,
events, videos, each stream) that a checking child read whole is read with the ordinary readers of :mod:`.reader`; a part
with damage in it is read around the damage (other registrations, other calibrations, the node rows whose id, label
and position survive, the stream rows outside the unreadable chunks); whatever is read is checked as a journal entry
would be (:mod:`.entries`), so a wrong type in the file is reported rather than raised. Every part left out or cut
short is named in ``problems``, in words.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import h5py
import numpy as np

from snreg.landmarks import NODE
from snreg.session import reader
from snreg.session.entries import EntryError, check_entry, check_node
from snreg.session import filecheck
from snreg.session.filecheck import FileCheck
from snreg.session.schema import STREAM_DTYPES, STREAM_SINCE, IntraopNode

__all__ = ["FileParts", "read_parts", "stream_rows", "stream_problem"]

_ESSENTIAL = ("id", "label", "xyz_trocar")          # a node row is kept when these survive
_DEFAULTS = {"time_ns": 0, "xyz_camera": [float("nan")] * 3, "spread_mm": float("nan"), "n_frames": 0,
             "counts": float("nan"), "left_jpeg": "", "right_jpeg": "", "earth_from_imu": None,
             "stereo_version": "", "chain_version": "", "trocar_camera_mm": float("nan"), "cov_trocar_mm2": None,
             "kind": NODE}                          # files before format 5 (no kind column) hold nodes only


@dataclass
class FileParts:
    """The parts read from the file (JSON forms, as the journal holds them; nodes as :class:`IntraopNode`) and one
    sentence per part that was damaged."""

    nodes: list = field(default_factory=list)
    calibration: dict = field(default_factory=dict)
    preop: dict | None = None
    registrations: list = field(default_factory=list)
    events: list = field(default_factory=list)
    videos: list = field(default_factory=list)
    problems: list[str] = field(default_factory=list)


def read_parts(h5: h5py.File, check: FileCheck | None) -> FileParts:
    """Every part of the session in ``h5`` that can be read (``check`` None: the file is trusted whole)."""
    parts = FileParts()
    for name, read in (("nodes", _nodes), ("calibration", _calibration), ("preop", _preop),
                       ("registrations", _registrations), ("events", _events),
                       ("videos", _videos)):
        try:
            setattr(parts, name, read(h5, check, parts.problems))
        except Exception as err:                        # noqa: BLE001 - any other surprise in a part costs that part
            parts.problems.append(f"{name}: unreadable ({_short(err)})")
    return parts


def stream_rows(h5: h5py.File | None, check: FileCheck | None) -> tuple[FileCheck | None, dict]:
    """(``check``, every ``streams/<name>``): the datasets themselves in a session being recorded (``check`` None,
    lazily read); else their readable rows as arrays, read by one child when the check left them for later (``check``
    then says what it could not read). No rows for a stream missing, unreadable or not a stream table."""
    out, deferred = {name: np.zeros(0, dtype) for name, dtype in STREAM_DTYPES.items()}, []
    for name, dtype in STREAM_DTYPES.items():
        path = f"/streams/{name}"
        if h5 is None or (check is not None and not check.dataset_opens(path)):
            continue
        try:
            dataset = h5[path]
            if not isinstance(dataset, h5py.Dataset) or dataset.dtype != dtype or dataset.ndim != 1:
                continue
            if check is None:
                out[name] = dataset
            elif path.startswith(check.deferred) and path not in check.rows_read:
                deferred.append(dataset)
            else:
                out[name] = _rows_around(dataset, check.bad_blocks(path))
        except (KeyError, OSError, ValueError, RuntimeError, TypeError):
            continue
    if deferred:
        check, rows = filecheck.read_rows(check, deferred)
        out.update({name.rpartition("/")[2]: values for name, values in rows.items()})
    return check, out


def stream_problem(h5: h5py.File | None, name: str, check: FileCheck | None) -> str | None:
    """One sentence when ``streams/<name>`` is missing, of the wrong kind or partly unreadable, else None."""
    path = f"/streams/{name}"
    if h5 is None:
        return None
    if check is not None and not check.clean_path(path):
        return f"stream {name}: unreadable ({check.cause(path)})"
    try:
        dataset = h5[path]
    except KeyError:
        return None if _older_than(h5, STREAM_SINCE.get(name)) else f"stream {name}: missing"
    except (OSError, ValueError, RuntimeError, TypeError) as err:
        return f"stream {name}: unreadable ({_short(err)})"
    try:
        wrong = not isinstance(dataset, h5py.Dataset) or dataset.dtype != STREAM_DTYPES[name] or dataset.ndim != 1
    except (OSError, ValueError, RuntimeError, TypeError) as err:     # e.g. a column name that is not UTF-8
        return f"stream {name}: its columns cannot be read ({_short(err)}); left out"
    if wrong:
        return f"stream {name}: not a {name} table (wrong columns); left out"
    bad = check.bad_blocks(path) if check is not None else set()
    held = filecheck.held_rows(dataset)
    if bad:
        step = filecheck.block_rows(dataset.shape, dataset.chunks)
        lost = sum(min(step, held - first) for first in bad)
        return f"stream {name}: {lost} of {held} rows unreadable ({check.cause(path)}); the rest kept"
    if held < dataset.shape[0]:
        return f"stream {name}: claims {dataset.shape[0]} rows but its chunks hold {held}; those {held} kept"
    return None


def _older_than(h5: h5py.File, version: int | None) -> bool:
    """Whether the file's ``format_version`` is below ``version`` (a stream introduced then may be absent from it);
    False when ``version`` is None or the attribute cannot be read."""
    if version is None:
        return False
    try:
        found = h5.attrs.get("format_version")
        return isinstance(found, (int, np.integer)) and int(found) < version
    except (OSError, ValueError, KeyError, RuntimeError, TypeError):
        return False


def _rows_around(dataset: h5py.Dataset, bad: set[int]) -> np.ndarray:
    """Every row outside the blocks starting at ``bad`` (each one block long: :func:`.filecheck.block_rows`)."""
    step = filecheck.block_rows(dataset.shape, dataset.chunks)
    held = filecheck.held_rows(dataset)
    parts = [dataset[first:min(first + step, held)] for first in range(0, held, step) if first not in bad]
    return np.concatenate(parts) if parts else np.zeros(0, dataset.dtype)


def _nodes(h5, check, problems) -> list[IntraopNode]:
    if "nodes" not in h5 or "intraop" not in h5["nodes"]:
        problems.append("nodes: the nodes/intraop table is missing")
        return []
    if check is None or check.clean("/nodes/intraop"):
        try:
            records = reader.read_nodes(h5)
        except (OSError, ValueError, KeyError, RuntimeError, TypeError, IndexError):
            records = None
        if records is not None:
            return _checked_nodes([record.to_json() for record in records], problems)
    return _nodes_by_column(h5["nodes/intraop"], check, problems)


def _checked_nodes(rows: list[dict], problems: list[str]) -> list[IntraopNode]:
    nodes, bad = [], []
    for k, row in enumerate(rows):
        try:
            nodes.append(IntraopNode.from_json(check_node(row)))
        except (EntryError, ValueError, TypeError) as err:
            bad.append(f"row {k + 1} {err}")
    if bad:
        problems.append(f"nodes/intraop: {len(bad)} of {len(rows)} rows left out ({'; '.join(bad[:3])})")
    return nodes


def _nodes_by_column(group: h5py.Group, check: FileCheck | None, problems: list[str]) -> list[IntraopNode]:
    """Node rows read column by column around the damage: a row is kept when its id, label and position survive."""
    columns = {}
    for name in list(_ESSENTIAL) + list(_DEFAULTS):
        path = f"/nodes/intraop/{name}"
        if check is not None and not check.dataset_opens(path):
            continue
        try:
            dataset = group[name]
            bad = check.bad_blocks(path) if check is not None else set()
            step = filecheck.block_rows(dataset.shape, dataset.chunks)
            held = filecheck.held_rows(dataset)
            values = [None] * held
            for first in range(0, held, step):
                if first not in bad:
                    values[first:first + step] = list(dataset[first:min(first + step, held)])
        except (KeyError, OSError, ValueError, RuntimeError, TypeError):
            continue
        columns[name] = values
    missing = [name for name in _ESSENTIAL if name not in columns]
    if missing:
        problems.append(f"nodes/intraop: the {', '.join(missing)} column(s) cannot be read; no node read from the file")
        return []
    rows, unknown_kind = [], []
    kinds, has_kind = columns.get("kind", []), _has_kind(group)
    for k in range(min(len(columns[name]) for name in _ESSENTIAL)):
        if has_kind and (k >= len(kinds) or kinds[k] is None):
            unknown_kind.append(k + 1)              # a landmark must never be read back as a node
            continue
        row = {}
        for name in list(_ESSENTIAL) + list(_DEFAULTS):
            value = columns[name][k] if name in columns and k < len(columns[name]) else None
            row[name] = _DEFAULTS.get(name) if value is None else _plain(name, value)
        if row["earth_from_imu"] is None:
            del row["earth_from_imu"]
        rows.append(row)
    if unknown_kind:
        problems.append(f"nodes/intraop: rows {', '.join(map(str, unknown_kind[:5]))} left out: whether each is a node "
                        "or a landmark cannot be read (the journal may still hold them)")
    if check is not None and not check.clean("/nodes/intraop"):
        problems.append(f"nodes/intraop: damaged ({check.cause('/nodes/intraop')}); read around the damage")
    return _checked_nodes(rows, problems)


def _has_kind(group: h5py.Group) -> bool:
    """Whether the node table has a ``kind`` column (format 5), readable or not."""
    try:
        return "kind" in group
    except (OSError, ValueError, RuntimeError, TypeError):
        return True


def _plain(name: str, value):
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if name in ("left_jpeg", "right_jpeg"):
        return bytes(np.asarray(value, dtype=np.uint8)).hex()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _calibration(h5, check, problems) -> dict:
    if "calibration" not in h5:
        return {}
    out = {}
    for kind in list(h5["calibration"]):
        path = f"/calibration/{kind}"
        if check is not None and not check.clean(path):
            problems.append(f"calibration {kind}: left out ({check.cause(path)})")
            continue
        data = _read(problems, f"calibration {kind}", lambda k=kind: check_entry(
            "calibration", {"kind": k, "data": reader.read_calibration(h5["calibration"][k])}))
        if data is not None:
            out[kind] = data["data"]
    return out


def _preop(h5, check, problems) -> dict | None:
    if check is not None and not check.clean("/nodes/preop"):
        problems.append(f"preop nodes: left out ({check.cause('/nodes/preop')})")
        return None
    data = _read(problems, "preop nodes", lambda: reader.read_preop(h5))
    return None if data is None else _read(problems, "preop nodes", lambda: check_entry("preop", data))


def _registrations(h5, check, problems) -> list[dict]:
    return _numbered(h5, check, problems, "registration", lambda group, n: reader.read_registration(group, int(n)))


def _videos(h5, check, problems) -> list[dict]:
    return _numbered(h5, check, problems, "video", lambda group, n: reader.read_video(group))


def _numbered(h5, check, problems, kind: str, read) -> list[dict]:
    """The ``<kind>s/<n>`` (``registration/<n>``) groups in order, each read by ``read(group, n)`` and checked as a
    journal entry of ``kind``; one that is damaged or not numbered is left out and named."""
    folder = "registration" if kind == "registration" else f"{kind}s"
    if folder not in h5:
        return []
    if check is not None and (not check.clean_path(f"/{folder}") or f"/{folder}/*" in check.problems):
        problems.append(f"{kind}s: none read from the file ({check.cause(f'/{folder}')})")
        return []
    out = []
    for name in reader.numbered_names(h5[folder]):
        path = f"/{folder}/{name}"
        if not name.isdigit() or (check is not None and not check.clean(path)):
            problems.append(f"{kind} {name}: left out ({check.cause(path) if check else 'not a number'})")
            continue
        data = _read(problems, f"{kind} {name}", lambda n=name: check_entry(kind, read(h5[folder][n], n)))
        if data is not None:
            out.append(data)
    return out


def _events(h5, check, problems) -> list[dict]:
    if "events" not in h5:
        return []
    dataset = h5["events"]
    if check is not None and not check.clean_path("/events"):
        problems.append(f"events: left out ({check.cause('/events')})")
        return []
    bad = check.bad_blocks("/events") if check is not None else set()
    raw = _rows_around(dataset, bad) if bad else dataset[()]
    out, left_out = [], 0
    for value in np.atleast_1d(raw):
        try:
            out.append(check_entry("event", json.loads(_plain("event", value))))
        except (EntryError, ValueError, TypeError, AttributeError, RecursionError):
            left_out += 1
    if left_out or bad:
        problems.append(f"events: {left_out} unreadable row(s) left out"
                        + (f", and damaged chunks ({check.cause('/events')})" if bad else ""))
    return out


def _read(problems: list[str], what: str, read):
    """``read()``, or None with one sentence in ``problems`` when the file's content makes it fail."""
    try:
        return read()
    except (EntryError, OSError, ValueError, KeyError, RuntimeError, TypeError, AttributeError) as err:
        problems.append(f"{what}: left out ({_short(err)})")
        return None


def _short(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 120 else text[:117] + "..."
