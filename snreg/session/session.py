"""The session object: create, open (HDF5 file merged with its journal), resume, read and close a session;
what it writes while recording is in :mod:`snreg.session.recording`."""

from __future__ import annotations

import datetime
import os
import tempfile
import threading
from pathlib import Path

import h5py
import numpy as np

from snreg import __version__
from snreg.chain import ChainCalibration
from snreg.landmarks import LANDMARK, NODE
from snreg.nodes import NodeSet, no_nodes
from snreg.preop.gravity import PreopDown
from snreg.session import opening, reader, salvage, writer
from snreg.session.journal import Journal, fsync_directory, journal_path
from snreg.session.recording import Recording, serialised
from snreg.session.schema import (FORMAT, FORMAT_VERSION, STREAM_DTYPES, IntraopNode, SessionError, StoredRegistration,
                                  calibration_version, stereo_from_dict, validate_case_id)
from snreg.session.video import VideoSegment


class Session(Recording):
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
        self._videos: dict[int, dict] = {}          # recorded video segments by number, in their JSON form
        self._recorder = None                       # the video segment being recorded, if any
        self._video_waiting = False                 # its encoder has not taken a pair yet
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
        journal = Journal.start(journal_path(path), "session", header)    # claims the name: refused when taken
        handle, building = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".creating", dir=path.parent)
        os.close(handle)
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
            state = (merged.header, merged.intraop_records(kind=None), dict(merged._calibration), merged._preop,
                     list(merged._registrations), list(merged._events), merged._final, dict(merged._videos))
        header, nodes, calibration, preop, registrations, events, final, videos = state
        try:
            h5 = h5py.File(path, "r+")
        except OSError as err:
            raise SessionError(f"{path}: cannot be opened for writing ({err}); is it open in another program?") from None
        header = {**header, "format_version": FORMAT_VERSION}
        session = cls(path, header, h5, Journal(journal_path(path)), damaged=False)
        session._nodes = {node.id: node for node in nodes}
        session._calibration, session._preop = calibration, preop
        writer.require_tables(h5)
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
        for data in videos.values():
            writer.write_video(h5, data)
        session._videos = videos
        h5.flush()
        session._buffers = {name: writer.StreamBuffer(h5, name, stream_flush_s) for name in STREAM_DTYPES}
        return session

    def _load_hdf5(self, parts: salvage.FileParts | None = None) -> None:
        """The file's parts (``parts``: as a checking child already read them), streams' problems said in words."""
        parts = parts or salvage.read_parts(self._h5, self._check)
        self._nodes.update({node.id: node for node in parts.nodes})
        self._calibration.update(parts.calibration)
        self._preop, self._events, self._registrations = parts.preop, parts.events, parts.registrations
        self._videos = {int(data["n"]): data for data in parts.videos}
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
            elif kind == "video":
                self._videos[int(data["n"])] = data

    # -- reading -------------------------------------------------------------
    @property
    def case_id(self) -> str:
        return str(self.header.get("case_id", ""))

    def intraop_records(self, kind: str | None = NODE) -> list[IntraopNode]:
        """The stored intraop points in the order stored: the nodes (default), the landmarks (``"landmark"``) or both
        (None: what is re-tracked, re-expressed and copied with the nodes)."""
        return [r for r in self._nodes.values() if kind is None or r.kind == kind]

    def intraop_nodes(self) -> NodeSet:
        """The stored nodes in the trocar frame (mm), landmarks never among them; counts None when no node has any,
        cov (mm^2) None when no node has one (a node's NaN when its own is unknown)."""
        return _point_set(self.intraop_records())

    def intraop_landmarks(self) -> NodeSet:
        """The stored landmarks in the trocar frame (mm), ids = their names (empty when none); as
        ``register(..., intraop_landmarks=)`` takes them."""
        return _point_set(self.intraop_records(LANDMARK))

    def preop_nodes(self) -> NodeSet | None:
        p = self._preop
        return None if p is None else NodeSet(p["ids"], p["labels"], p["xyz"], p["counts"], frame=p["frame"],
                                              cov=p.get("cov"))

    def preop_down(self) -> PreopDown | None:
        """What gives the down in the preop nodes' frame (the SPECT's patient position, the table's tilt), kept with
        them; None when not known (not stored with them, or files written before it was)."""
        down = None if self._preop is None else self._preop.get("down")
        return None if down is None else PreopDown.from_json(down)

    def intraop_down(self) -> np.ndarray:
        """(3,) unit gravity in the trocar frame of the stored nodes: the IMU's down through the stored chain's
        reference (:attr:`ChainCalibration.down_trocar`). SessionError in one sentence when no chain is stored, or
        when a node was mapped with a chain other than the stored one (re-express the nodes under it first)."""
        chain = self._calibration.get("chain")
        if chain is None:
            raise SessionError(f"{self.path}: the session holds no chain calibration, so gravity's direction in its "
                               "trocar frame is unknown")
        version = calibration_version(chain)
        others = sorted({node.chain_version for node in self._nodes.values()} - {version, ""})
        if others:
            raise SessionError(f"{self.path}: nodes were mapped with chain {', '.join(others)}, not the stored chain "
                               f"{version}, so gravity's direction in their frame is unknown; re-express them under "
                               "the stored chain")
        return ChainCalibration.from_dict(chain).down_trocar
    def preop_landmarks(self) -> NodeSet:
        """The preop landmarks stored with the preop nodes (their frame, mm; ids = names); empty when none."""
        p = self._preop or {}
        marks = p.get("landmarks")
        return no_nodes(p.get("frame", "")) if marks is None else NodeSet(marks["ids"], marks["labels"], marks["xyz"],
                                                                           frame=p.get("frame", ""))

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

    def events(self, kind: str | None = None) -> list[dict]:
        """The events on record, oldest first; only those of ``kind`` if given."""
        return [dict(event) for event in self._events if kind is None or event["kind"] == kind]

    def final_registration(self) -> int | None:
        """The number of the registration marked final, None if none is."""
        return self._final

    def videos(self) -> list[VideoSegment]:
        """The recorded video segments, in order (the one being recorded as it was started)."""
        return [VideoSegment.from_json(self._videos[n]) for n in sorted(self._videos)]

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
            for node in self.intraop_records(kind=None):
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
            for data in self._videos.values():
                writer.write_video(h5, data)
            for name in STREAM_DTYPES:
                source = self.stream(name)
                rows = reader.readable_rows(source) if isinstance(source, h5py.Dataset) else source
                h5[f"streams/{name}"].resize(len(rows), axis=0)
                h5[f"streams/{name}"][:] = rows

    # -- closing -------------------------------------------------------------
    @serialised
    def close(self) -> None:
        """Finish the video being recorded, flush buffered streams and close the files (idempotent)."""
        if self._recorder is not None:
            self.stop_video()
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


def _point_set(records: list[IntraopNode]) -> NodeSet:
    """Stored points as a node set, trocar frame; counts and cov None when no point has any."""
    counts = np.array([r.counts for r in records], dtype=float)
    cov = np.array([r.cov_trocar_mm2 for r in records], dtype=float).reshape(-1, 3, 3)
    return NodeSet([r.id for r in records], [r.label for r in records],
                   np.array([r.xyz_trocar for r in records], dtype=float).reshape(-1, 3),
                   counts if np.any(np.isfinite(counts)) else None, frame="trocar",
                   cov=cov if np.any(np.isfinite(cov)) else None)
