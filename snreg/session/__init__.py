"""Crash-safe HDF5 sessions (DESIGN.md §4 "Session (HDF5)").

>>> with Session.create("s.h5", case_id="phantom-01") as s:
...     s.add_intraop_node("SN1", "OBT R", [1.0, 2.0, 3.0])   # durable once it returns
>>> Session.open("s.h5").intraop_nodes()                    # NodeSet, frame "trocar"

Nodes, node removals (undo), calibrations, preop sets and registrations go to a write-ahead journal
(``s.h5.journal``, fsynced) before the HDF5 file; :meth:`Session.open` merges the journal, and reads it alone
when a kill left the HDF5 file unreadable (``Session.damaged``); ``snreg session recover`` rebuilds a clean
file. :meth:`Session.resume` reopens a session to go on recording into it. The journal keeps every node ever
stored, so an undone node stays on record there.

One stored registration may be marked final, the one that counts (:meth:`Session.set_final_registration`;
:func:`set_final_in_file` for a closed file): the attribute ``final=True`` on ``registration/<n>``, journal first;
files without it have none marked.

What happened besides the nodes (a store refused and why, nodes re-expressed under a new calibration with their old
values, an acquisition started) goes to the ``events`` log (:meth:`Session.log_event`, :meth:`Session.events`),
journal first as well. A re-expression is one journal line, so a kill during it leaves every node either all old
or all new, never half.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import os
import threading
import time
from pathlib import Path

import h5py
import numpy as np

from snreg import __version__
from snreg.chain import ChainCalibration
from snreg.nodes import INTRAOP_PREFIX, NodeSet
from snreg.session import opening, reader, salvage, writer
from snreg.session.journal import Journal, fsync_directory, journal_path
from snreg.session.schema import (FORMAT, FORMAT_VERSION, STREAM_DTYPES, IntraopNode, SessionError, StoredRegistration,
                                  calibration_version, jpeg_bytes, position_mm, stereo_from_dict, stereo_to_dict,
                                  validate_case_id)

__all__ = ["Session", "SessionError", "IntraopNode", "StoredRegistration", "read_intraop_nodes", "validate_case_id",
           "calibration_version", "set_final_in_file"]


def _serialised(method):
    """Run a writing method under the session's lock: the acquisition worker (nodes, streams) and the
    registration panel's worker (preop, results) may write at the same time from their own threads."""
    @functools.wraps(method)
    def locked(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)
    return locked


class Session:
    """A session being recorded (:meth:`create`) or read (:meth:`open`); use it as a context manager."""

    def __init__(self, path: Path, header: dict, h5: h5py.File | None, journal: Journal | None, damaged: bool):
        self.path, self.header, self._h5, self._journal, self.damaged = path, header, h5, journal, damaged
        self._nodes: dict[str, IntraopNode] = {}
        self._calibration: dict[str, dict] = {}
        self._preop: dict | None = None
        self._registrations: list[dict] = []
        self._final: int | None = None              # the registration marked final, if any
        self._events: list[dict] = []
        self._buffers: dict[str, writer.StreamBuffer] = {}
        self._lock = threading.RLock()
        self._check = None                          # what a child could read of the file (opened sessions)
        self._streams: dict[str, np.ndarray] = {}   # stream rows read so far (opened sessions)
        self.problems: list[str] = []               # what could not be read, in words (opened sessions)
        self.has_journal = journal is not None

    # -- opening -------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path, case_id: str, *, stream_flush_s: float = 1.0) -> "Session":
        """A new session at ``path`` (refused if it or its journal exists); streams flush every ``stream_flush_s`` s."""
        path = Path(path)
        header = {"format": FORMAT, "format_version": FORMAT_VERSION, "case_id": validate_case_id(case_id),
                  "created_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                  "snreg_version": __version__}
        if path.exists() or journal_path(path).exists():
            raise SessionError(f"{path}: a session (or its journal) already exists there; choose a new file name")
        # A kill at any moment leaves nothing, a journal holding the header (opens, empty; 'recover' writes the
        # file), or both files whole: each is built under a temporary name and renamed into place.
        journal = Journal.start(journal_path(path), "session", header)
        building = path.with_name(f".{path.name}.creating")
        with h5py.File(building, "w") as h5:
            writer.init_file(h5, header)
        with open(building, "rb+") as file:
            os.fsync(file.fileno())
        os.replace(building, path)
        fsync_directory(path.parent)
        h5 = h5py.File(path, "r+")
        session = cls(path, header, h5, journal, damaged=False)
        session._buffers = {name: writer.StreamBuffer(h5, name, stream_flush_s) for name in STREAM_DTYPES}
        return session

    @classmethod
    def open(cls, path: str | Path) -> "Session":
        """Read a session (never opened for writing); :class:`SessionError` in one sentence when it cannot be.

        Whatever can still be read is: the HDF5 file is read first in a child process (:mod:`.filecheck`), so damage
        that would crash libhdf5 marks the session ``damaged``; ``problems`` says in words what could not be read."""
        path = Path(path)
        opened = opening.open_parts(path)
        session = cls(path, opened.header, opened.h5, None, damaged=opened.damaged)
        session._check, session.problems, session.has_journal = opened.check, opened.problems, opened.journal
        if opened.h5 is not None:
            session._load_hdf5(opened.parts)
        session._replay(opened.entries)
        return session

    @classmethod
    def resume(cls, path: str | Path, *, stream_flush_s: float = 1.0) -> "Session":
        """Reopen a session to go on recording (after a restart or a crash); what only the journal held is written
        into the HDF5 file first. A damaged HDF5 file is refused: run ``snreg session recover`` on it."""
        path = Path(path)
        if not path.exists():
            raise SessionError(f"{path}: no such session file")
        with cls.open(path) as merged:
            if merged.damaged:
                raise SessionError(f"{path}: the HDF5 file is damaged; run 'snreg session recover' on it, "
                                   "then continue the recovered file")
            state = (merged.header, merged.intraop_records(), dict(merged._calibration), merged._preop,
                     list(merged._registrations), list(merged._events), merged._final)
        header, nodes, calibration, preop, registrations, events, final = state
        try:
            h5 = h5py.File(path, "r+")
        except OSError as err:
            raise SessionError(f"{path}: cannot be opened for writing ({err}); is it open in another program?") from None
        header = {**header, "format_version": FORMAT_VERSION}
        session = cls(path, header, h5, Journal(journal_path(path)), damaged=False)
        session._nodes = {node.id: node for node in nodes}
        session._calibration, session._preop = calibration, preop
        writer.require_v2_tables(h5)
        logged = {event.get("n") for event in reader.read_events(h5)}
        for event in events:
            if event.get("n") not in logged:
                writer.append_event(h5, event)
        session._events = events
        written = {int(n) for n in h5["registration"]}
        for kind, data in calibration.items():
            writer.write_calibration(h5, kind, data)
        if preop is not None:
            writer.write_preop(h5, preop)
        for data in registrations:
            if data["n"] not in written:
                writer.write_registration(h5, data)
        session._registrations, session._final = registrations, final
        writer.write_final(h5, final)
        writer.rewrite_nodes(h5, nodes)
        h5.flush()
        session._buffers = {name: writer.StreamBuffer(h5, name, stream_flush_s) for name in STREAM_DTYPES}
        return session

    def _load_hdf5(self, parts: salvage.FileParts | None = None) -> None:
        """The file's parts (``parts``: as a checking child already read them), streams' problems said in words."""
        parts = parts or salvage.read_parts(self._h5, self._check)
        self._nodes.update({node.id: node for node in parts.nodes})
        self._calibration.update(parts.calibration)
        self._preop, self._events, self._registrations = parts.preop, parts.events, parts.registrations
        self._final = next((r["n"] for r in parts.registrations if r.get("final")), None)
        problems = parts.problems + [p for name in STREAM_DTYPES
                                     if (p := salvage.stream_problem(self._h5, name, self._check))]
        self.problems += problems
        self.damaged = self.damaged or bool(problems)

    def _replay(self, entries: list) -> None:
        """Merge journal entries over what the HDF5 file holds (the journal is never behind it)."""
        known = {reg["n"] for reg in self._registrations}
        logged = {event.get("n") for event in self._events}
        for kind, data in entries:
            if kind == "node":
                self._nodes[data["id"]] = IntraopNode.from_json(data)
            elif kind == "node_removed":
                self._nodes.pop(data["id"], None)
            elif kind in ("event", "nodes_reexpressed"):
                if kind == "nodes_reexpressed":
                    self._apply_reexpression(data)
                if data.get("n") not in logged:
                    self._events.append(data)
                    logged.add(data.get("n"))
            elif kind == "calibration":
                self._calibration[data["kind"]] = data["data"]
            elif kind == "preop":
                self._preop = data
            elif kind == "registration" and data["n"] not in known:
                self._registrations.append(data)
                known.add(data["n"])
            elif kind == "final":
                self._final = data["n"]

    # -- writing -------------------------------------------------------------
    @_serialised
    def add_intraop_node(self, node_id: str, label: str, xyz_trocar, *, xyz_camera=None, spread_mm: float = float("nan"),
                         n_frames: int = 0, counts: float = float("nan"), time_ns: int | None = None,
                         left_jpeg=b"", right_jpeg=b"", earth_from_imu=None, stereo_version: str = "",
                         chain_version: str = "") -> IntraopNode:
        """Store a node (positions mm; time ns on the host clock, perf_counter_ns like the streams); on disk when this returns.

        Snapshots are JPEG bytes or images (H, W[, 3]) uint8, encoded here. ``earth_from_imu`` (3, 3) and the
        calibration versions say what the node was measured with (see :class:`IntraopNode`).
        """
        self._writable()
        node_id = str(node_id)
        if node_id in self._nodes:
            raise SessionError(f"{self.path}: node id {node_id!r} is already stored; use a new id")
        nan3 = np.full(3, np.nan)
        node = IntraopNode(node_id, str(label), time.perf_counter_ns() if time_ns is None else int(time_ns),
                           position_mm(xyz_trocar), nan3 if xyz_camera is None else position_mm(xyz_camera), float(spread_mm),
                           int(n_frames), float(counts), jpeg_bytes(left_jpeg), jpeg_bytes(right_jpeg),
                           np.full((3, 3), np.nan) if earth_from_imu is None
                           else np.asarray(earth_from_imu, dtype=float).reshape(3, 3),
                           str(stereo_version), str(chain_version))
        self._journal.append("node", node.to_json())
        writer.write_node(self._h5, node)
        self._h5.flush()
        self._nodes[node_id] = node
        return node

    @_serialised
    def remove_intraop_node(self, node_id: str) -> IntraopNode:
        """Take back a stored node (undo); durable when this returns. The journal keeps the node on record."""
        self._writable()
        node_id = str(node_id)
        if node_id not in self._nodes:
            raise SessionError(f"{self.path}: there is no stored node {node_id!r} to remove")
        self._journal.append("node_removed", {"id": node_id})
        node = self._nodes.pop(node_id)
        writer.rewrite_nodes(self._h5, list(self._nodes.values()))
        self._h5.flush()
        return node

    @_serialised
    def reexpress_nodes(self, nodes: list[IntraopNode], reason: str) -> dict:
        """Replace stored nodes by the same nodes re-expressed (new positions and calibration versions, same ids),
        all or none: one journal line holds them with their old values, which stay on record in the ``events`` log
        (kind ``nodes_reexpressed``). Returns that event."""
        self._writable()
        missing = [node.id for node in nodes if node.id not in self._nodes]
        if missing:
            raise SessionError(f"{self.path}: there is no stored node {missing[0]!r} to re-express")
        keys = ("xyz_trocar", "xyz_camera", "stereo_version", "chain_version")
        changes = []
        for node in nodes:
            old = self._nodes[node.id]
            changes.append({"id": node.id, **_plain_values(node, keys),
                            "old": _plain_values(old, keys)})
        event = {"n": len(self._events), "kind": "nodes_reexpressed", "time_ns": time.perf_counter_ns(),
                 "reason": str(reason), "nodes": changes}
        self._journal.append("nodes_reexpressed", event)
        self._apply_reexpression(event)
        self._events.append(event)
        writer.rewrite_nodes(self._h5, list(self._nodes.values()))
        writer.append_event(self._h5, event)
        self._h5.flush()
        return event

    def _apply_reexpression(self, event: dict) -> None:
        for change in event["nodes"]:
            node = self._nodes.get(change["id"])
            if node is not None:
                self._nodes[node.id] = dataclasses.replace(
                    node, xyz_trocar=np.asarray(change["xyz_trocar"], dtype=float),
                    xyz_camera=np.asarray(change["xyz_camera"], dtype=float),
                    stereo_version=str(change["stereo_version"]), chain_version=str(change["chain_version"]))

    @_serialised
    def log_event(self, kind: str, **data) -> dict:
        """Put what happened (``kind``, e.g. ``store_refused`` with its ``reason``) on record, durable on return;
        host time ns is added. Returns the event."""
        self._writable()
        event = {"n": len(self._events), "kind": str(kind), "time_ns": time.perf_counter_ns(), **data}
        self._journal.append("event", event)
        writer.append_event(self._h5, event)
        self._h5.flush()
        self._events.append(event)
        return event

    def events(self, kind: str | None = None) -> list[dict]:
        """The events on record, oldest first; only those of ``kind`` if given."""
        return [dict(event) for event in self._events if kind is None or event["kind"] == kind]

    def next_node_id(self, prefix: str = INTRAOP_PREFIX) -> str:
        """The first ``<prefix><k>`` (k = 1, 2, ...) not stored: after an undo the id is used again."""
        k = 1
        while f"{prefix}{k}" in self._nodes:
            k += 1
        return f"{prefix}{k}"

    @property
    def writable(self) -> bool:
        return self._journal is not None

    @_serialised
    def set_calibration(self, *, stereo=None, chain=None) -> None:
        """Store a :class:`~snreg.camera.StereoCalibration` and/or a :class:`~snreg.chain.ChainCalibration`."""
        self._writable()
        items = ([("stereo", stereo_to_dict(stereo))] if stereo is not None else []) + \
                ([("chain", chain.to_dict())] if chain is not None else [])
        for kind, data in items:
            self._journal.append("calibration", {"kind": kind, "data": data})
            writer.write_calibration(self._h5, kind, data)
            self._calibration[kind] = data
        self._h5.flush()

    @_serialised
    def set_preop_nodes(self, nodes: NodeSet) -> None:
        self._writable()
        data = {"ids": nodes.ids, "labels": nodes.labels, "xyz": nodes.xyz.tolist(),
                "counts": None if nodes.counts is None else nodes.counts.tolist(), "frame": nodes.frame}
        self._journal.append("preop", data)
        writer.write_preop(self._h5, data)
        self._h5.flush()
        self._preop = data

    @_serialised
    def add_registration(self, result, preop_ids, intraop_ids) -> int:
        """Store a :class:`~snreg.registration.RegistrationResult` as ``registration/<n>`` with the ids of the preop
        and intraop nodes it paired (so it stays readable after an undo or a re-segmentation) and the initial
        alignment it started from; returns n."""
        self._writable()
        preop_ids, intraop_ids = [str(i) for i in preop_ids], [str(i) for i in intraop_ids]
        pairing = np.asarray(result.pairing, dtype=int)
        if len(intraop_ids) != len(pairing) or int(pairing.max(initial=-1)) >= len(preop_ids):
            raise SessionError(f"{self.path}: the registration pairs {len(pairing)} intraop nodes with preop indices "
                               f"up to {int(pairing.max(initial=-1))}, but {len(intraop_ids)} intraop and "
                               f"{len(preop_ids)} preop ids were given; give the ids of the node sets it was run on")
        def optional(name):
            value = getattr(result, name, None)
            return None if value is None else np.asarray(value).tolist()

        data = {"n": len(self._registrations), "method": result.method, "rms_mm": float(result.rms_mm),
                "pairing_rule": result.pairing_rule, "transform": np.asarray(result.transform).tolist(),
                "pairing": pairing.tolist(), "distances_mm": np.asarray(result.distances_mm).tolist(),
                "confidence": np.asarray(result.confidence).tolist(), "preop_ids": preop_ids,
                "intraop_ids": intraop_ids,
                **{name: optional(name) for name in ("initial", "target_error_mm", "missing", "leave_one_out_mm")}}
        self._journal.append("registration", data)
        writer.write_registration(self._h5, data)
        self._h5.flush()
        self._registrations.append(data)
        return data["n"]

    @_serialised
    def set_final_registration(self, n: int | None) -> None:
        """Mark stored registration ``n`` as the final one, the one that counts (exports use it); None unmarks.
        At most one is final: marking another moves the mark. Durable when this returns (journal line, then the
        ``final`` attribute on ``registration/<n>`` and a flush); no node or registration data is rewritten."""
        self._writable()
        n = self._known_registration(n)
        self._journal.append("final", {"n": n})
        writer.write_final(self._h5, n)
        self._h5.flush()
        self._final = n

    def _known_registration(self, n: int | None) -> int | None:
        if n is None:
            return None
        if int(n) not in {r["n"] for r in self._registrations}:
            raise SessionError(f"{self.path}: there is no stored registration {n} to mark final; "
                               f"stored: {', '.join(str(r['n']) for r in self._registrations) or 'none'}")
        return int(n)

    def final_registration(self) -> int | None:
        """The number of the registration marked final, None if none is."""
        return self._final

    def append_imu(self, t_host_ns, t_device_ns, acc_g, gyro_dps) -> None:
        """IMU samples: times (n,) ns, acceleration (n, 3) g, angular rate (n, 3) deg/s."""
        self._append("imu", t_host_ns=t_host_ns, t_device_ns=t_device_ns, acc_g=acc_g, gyro_dps=gyro_dps)

    def append_probe(self, t_host_ns, t_device_ns, tip_mm, centre_mm, axis, quality) -> None:
        """Probe poses: times (n,) ns, tip and centre (n, 3) mm camera frame, axis (n, 3) unit, quality (n,)."""
        self._append("probe", t_host_ns=t_host_ns, t_device_ns=t_device_ns, tip_mm=tip_mm, centre_mm=centre_mm,
                     axis=axis, quality=quality)

    def append_frames(self, t_host_ns, t_device_ns, index) -> None:
        """Frame times (n,) ns and frame indices (n,)."""
        self._append("frames", t_host_ns=t_host_ns, t_device_ns=t_device_ns, index=index)

    @_serialised
    def _append(self, name: str, **columns) -> None:
        self._writable()
        n = np.atleast_1d(columns["t_host_ns"]).shape[0]
        rows = np.zeros(n, STREAM_DTYPES[name])
        for key, value in columns.items():
            rows[key] = np.asarray(value).reshape(rows[key].shape)
        self._buffers[name].append(rows)

    def _writable(self) -> None:
        if self._journal is None:
            raise SessionError(f"{self.path}: opened for reading; create a new session to record")

    # -- reading -------------------------------------------------------------
    @property
    def case_id(self) -> str:
        return str(self.header.get("case_id", ""))

    def intraop_records(self) -> list[IntraopNode]:
        return list(self._nodes.values())

    def intraop_nodes(self) -> NodeSet:
        """The stored nodes in the trocar frame (mm); counts None when no node has any."""
        records = self.intraop_records()
        counts = np.array([r.counts for r in records], dtype=float)
        return NodeSet([r.id for r in records], [r.label for r in records],
                       np.array([r.xyz_trocar for r in records], dtype=float).reshape(-1, 3),
                       counts if np.any(np.isfinite(counts)) else None, frame="trocar")

    def preop_nodes(self) -> NodeSet | None:
        p = self._preop
        return None if p is None else NodeSet(p["ids"], p["labels"], p["xyz"], p["counts"], frame=p["frame"])

    def calibration(self) -> dict:
        """``{"stereo": StereoCalibration, "chain": ChainCalibration}`` for those stored."""
        out = {}
        if "stereo" in self._calibration:
            out["stereo"] = stereo_from_dict(self._calibration["stereo"])
        if "chain" in self._calibration:
            out["chain"] = ChainCalibration.from_dict(self._calibration["chain"])
        return out

    def calibration_versions(self) -> tuple[str, str]:
        """(stereo, chain) :func:`calibration_version` of the calibrations stored now ("" for one not stored)."""
        return calibration_version(self._calibration.get("stereo")), calibration_version(self._calibration.get("chain"))

    def registrations(self) -> list[StoredRegistration]:
        """The stored registrations, in order: each :class:`~snreg.registration.RegistrationResult` with the ids of
        the nodes it paired (None in files written before ids were stored) and its final mark."""
        return [StoredRegistration.from_json(r, final=r["n"] == self._final) for r in self._registrations]

    def last_initial(self) -> np.ndarray | None:
        """The initial alignment (4, 4) kept with the last registration that kept one, None if none did: where
        registering these nodes again starts from."""
        kept = [r["initial"] for r in self._registrations if r.get("initial") is not None]
        return np.asarray(kept[-1], dtype=float) if kept else None

    def stream(self, name: str):
        """The ``streams/<name>`` table: lazily (an h5py dataset) in a session being recorded; in one opened for
        reading, its rows outside any damage (an array, read once by a child process), none when unreadable."""
        if name not in STREAM_DTYPES:
            raise SessionError(f"no stream {name!r}; streams are {', '.join(STREAM_DTYPES)}")
        if self._check is None:                         # being recorded: the table itself, as it grows
            return salvage.stream_rows(self._h5, None)[1][name]
        if not self._streams:                           # read once, all together, by a child (.filecheck)
            self._check, self._streams = salvage.stream_rows(self._h5, self._check)
        return self._streams[name]

    def save_as(self, path: str | Path) -> None:
        """Write everything this session holds, streams up to their first unreadable block, to a clean HDF5 file."""
        with h5py.File(path, "w") as h5:
            writer.init_file(h5, self.header)
            for node in self.intraop_records():
                writer.write_node(h5, node)
            for kind, data in self._calibration.items():
                writer.write_calibration(h5, kind, data)
            if self._preop is not None:
                writer.write_preop(h5, self._preop)
            for data in self._registrations:
                writer.write_registration(h5, data)
            writer.write_final(h5, self._final)
            for event in self._events:
                writer.append_event(h5, event)
            for name in STREAM_DTYPES:
                source = self.stream(name)
                rows = reader.readable_rows(source) if isinstance(source, h5py.Dataset) else source
                h5[f"streams/{name}"].resize(len(rows), axis=0)
                h5[f"streams/{name}"][:] = rows

    # -- closing -------------------------------------------------------------
    @_serialised
    def close(self) -> None:
        """Flush buffered streams and close the files (idempotent)."""
        if self._h5 is not None and self._h5.id.valid:
            for buffer in self._buffers.values():
                buffer.flush()
            self._h5.close()
        if self._journal is not None:
            self._journal.close()

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _plain_values(node: IntraopNode, keys) -> dict:
    return {key: np.asarray(getattr(node, key), dtype=float).tolist() if key.startswith("xyz")
            else str(getattr(node, key)) for key in keys}


def set_final_in_file(path: str | Path, n: int | None) -> None:
    """Mark registration ``n`` final (None: unmark) in a session file that is not open for recording (review).

    Journal line first, then the attribute, as :meth:`Session.set_final_registration`; unlike
    :meth:`Session.resume` nothing else is rewritten. :class:`SessionError` in one sentence when the file cannot be
    marked (no such registration, damaged, or open for recording elsewhere)."""
    path = Path(path)
    with Session.open(path) as session:
        if session.damaged:
            raise SessionError(f"{path}: the HDF5 file is damaged; run 'snreg session recover' before marking it")
        n = session._known_registration(n)
    try:
        h5 = h5py.File(path, "r+")
    except OSError as err:
        raise SessionError(f"{path}: cannot be opened for writing ({err}); is it being recorded?") from None
    with h5:
        journal = Journal(journal_path(path))
        try:
            journal.append("final", {"n": n})
        finally:
            journal.close()
        writer.write_final(h5, n)
        h5.flush()


def read_intraop_nodes(path: str | Path) -> NodeSet:
    """The intraop nodes of a session file (trocar frame, mm), for ``snreg register``."""
    with Session.open(path) as session:
        return session.intraop_nodes()

