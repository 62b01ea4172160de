"""Read a possibly damaged HDF5 file where a crash of libhdf5 cannot take the caller down.

Why: libhdf5 trusts a file's metadata. One flipped byte in an object header, a B-tree node or a heap can make it read
out of bounds and end the process with a segmentation fault (no exception, nothing on stderr), or loop forever. So
before a session file is read, :func:`check_file` forks a child that reads it the way the readers will: every
group's members, every attribute, every dataset, in blocks of chunks. The child names each key before it touches it
(in memory shared with the parent, no system call per key); when the child dies or stops making progress, the key it
named is marked unreadable and a new child reads the rest, leaving it out. The caller then reads only what a child
read without harm, so a damaged file costs what is damaged and no more. The streams' rows, most of a file's bytes and
not needed to open it, are left for :func:`read_rows`: one child reads them through the caller's own handle into
shared memory, so they are decompressed once. Nothing is cached between calls: every file is read afresh.

Keys name what was read: ``/nodes/intraop`` (the object), ``/nodes/intraop/*`` (its member list), ``/x@*`` (the
attribute list of ``/x``), ``/x@case_id`` (one attribute), ``/streams/imu#2048`` (the rows of the block starting at
row 2048; one block per chunk), ``/events#`` (a dataset read whole). A fork is cheap (the child shares the parent's
memory pages); a file this process has open for writing (the session being recorded) is not checked: libhdf5 reads
that one from what it holds in memory, and a child must not touch that state.
"""

from __future__ import annotations

import dataclasses
import mmap
import os
import pickle
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import h5py

from snreg.session.filechild import (MAX_RUNS, STALL_S, Job, block_rows, children, held_rows, run_child,
                                      walk_chunk_index)

if TYPE_CHECKING:
    import numpy as np

__all__ = ["FileCheck", "check_file", "read_checked", "read_rows", "walk_chunk_index", "held_rows", "block_rows",
           "STALL_S", "MAX_RUNS", "DEFERRED"]

_PAYLOAD_BYTES = 256 << 20  # shared memory for read_checked's value, touched only as far as written (parts: a few MB)
DEFERRED = ("/streams/",)   # most of a file's bytes, not needed to open it: their rows are read when they are used


@dataclass(frozen=True)
class FileCheck:
    """What a child could read of one file: ``problems`` maps each key it could not read to why (a key names an
    object, a member list, an attribute or a block of rows: module docstring); ``opens`` is False when the file
    itself cannot be opened, and ``why`` then says why (damaged, locked by a writer, no permission, not HDF5)."""

    path: Path
    opens: bool
    problems: dict[str, str] = field(default_factory=dict)
    why: str = ""
    runs: int = 0
    seconds: float = 0.0
    deferred: tuple[str, ...] = ()                  # prefixes of datasets whose rows are left to read_rows
    rows_read: frozenset[str] = frozenset()         # deferred datasets whose rows read_rows has read

    def clean(self, name: str) -> bool:
        """True when the object ``name`` (e.g. ``/nodes/intraop``), its attributes and everything under it read
        without a problem, and so did every group on the way to it."""
        if not self.opens:
            return False
        parts = name.strip("/").split("/") if name.strip("/") else []
        ancestors = ["/" + "/".join(parts[:k]) for k in range(len(parts))]
        for key in self.problems:
            if key == name or key.startswith((name.rstrip("/") + "/", name + "@", name + "#")):
                return False
            if any(key in (a, a.rstrip("/") + "/*") for a in ancestors):
                return False
        return True

    def attribute_ok(self, name: str, attribute: str) -> bool:
        """True when attribute ``attribute`` of object ``name`` was read (and its object and attribute list too)."""
        return (self.opens and not ({f"{name}@*", f"{name}@{attribute}"} & set(self.problems))
                and self.clean_path(name))

    def clean_path(self, name: str) -> bool:
        """True when ``name`` itself and every group on the way to it opened (what is under it may be damaged)."""
        parts = name.strip("/").split("/") if name.strip("/") else []
        on_the_way = {"/" + "/".join(parts[:k]) for k in range(len(parts) + 1)}
        return self.opens and not any(key in on_the_way or key in {p.rstrip("/") + "/*" for p in on_the_way}
                                      for key in self.problems)

    def cause(self, name: str) -> str:
        """Why ``name`` is not clean: the first problem at it, under it or on the way to it ("" when it is clean)."""
        parts = name.strip("/").split("/") if name.strip("/") else []
        on_the_way = {"/" + "/".join(parts[:k]) for k in range(len(parts) + 1)}
        for key, why in self.problems.items():
            if key.startswith((name.rstrip("/") + "/", name + "@", name + "#")) or key in on_the_way or \
                    key in {p.rstrip("/") + "/*" for p in on_the_way}:
                return why
        return self.why

    def dataset_opens(self, name: str) -> bool:
        """True when dataset ``name`` opens and its shape reads (its rows may still be partly damaged)."""
        return self.clean_path(name) and not ({f"{name}#", f"{name}#shape"} & set(self.problems))

    def bad_blocks(self, name: str) -> set[int]:
        """First rows of the blocks of dataset ``name`` that could not be read."""
        prefix = name + "#"
        return {int(key[len(prefix):]) for key in self.problems
                if key.startswith(prefix) and key[len(prefix):].isdigit()}

    @property
    def damaged(self) -> bool:
        return not self.opens or bool(self.problems)


def check_file(path: str | Path, *, defer: tuple[str, ...] = DEFERRED, stall_s: float = STALL_S) -> FileCheck:
    """Read all of ``path`` in forked children (module docstring); never raises for what the file holds.

    The rows of datasets under a ``defer`` prefix (the streams: most of a file's bytes, and not needed to open a
    session) are left for :func:`read_rows`; their objects, attributes, shapes and chunk indexes are read."""
    path = Path(path)
    start = time.perf_counter()
    if _open_here(path) or not hasattr(os, "fork"):
        return FileCheck(path, True, seconds=time.perf_counter() - start)
    problems, runs = children(path, {}, Job(defer=tuple(defer)), stall_s)
    why = problems.pop("/", "")
    return FileCheck(path, not why, problems, why, runs, time.perf_counter() - start, tuple(defer))


def read_checked(path: str | Path, read, *, defer: tuple[str, ...] = DEFERRED) -> tuple[FileCheck, object]:
    """(check, ``read(h5)``): ``read`` run first in a child on the file opened read-only, its value handed back (pickled,
    through shared memory). When it returns, the file is healthy for everything ``read`` touches (which must be all the
    caller reads when opening it): the check is clean and the caller need not read those parts again. When it fails
    (an exception, a crash, a hang), :func:`check_file` walks the file to say what is damaged, and the value is None.
    A file open for writing in this process is not read here: (a trusting check, None)."""
    path = Path(path)
    start = time.perf_counter()
    if _open_here(path) or not hasattr(os, "fork"):
        return FileCheck(path, True, seconds=time.perf_counter() - start), None
    sink = mmap.mmap(-1, _PAYLOAD_BYTES)
    finished, _, _ = run_child(path, set(), {}, STALL_S, Job(read=read, sink=sink))
    value = None
    if finished:
        size = struct.unpack_from("<Q", sink, 0)[0]
        value = pickle.loads(sink[8:8 + size]) if size else None
    sink.close()
    if value is not None:
        return FileCheck(path, True, runs=1, seconds=time.perf_counter() - start, deferred=tuple(defer)), value
    check = check_file(path, defer=defer)
    return dataclasses.replace(check, runs=check.runs + 1, seconds=time.perf_counter() - start), None


def read_rows(check: FileCheck, datasets: list[h5py.Dataset]) -> tuple[FileCheck, dict[str, np.ndarray]]:
    """Every readable row of deferred ``datasets`` of the file checked, read once, by children (through these very
    handles, as this process would), into memory shared with this process; and ``check`` with what they could not
    read. Each array (by dataset name) holds every row outside the damaged chunks, in order."""
    import numpy as np

    start = time.perf_counter()
    held = [held_rows(d) for d in datasets]
    sinks = [mmap.mmap(-1, max(1, rows * d.dtype.itemsize)) for d, rows in zip(datasets, held)]
    problems, runs = children(check.path, dict(check.problems), Job(only=tuple(zip(datasets, sinks))), STALL_S)
    if "/" in problems:                          # a child stopped outside any block: these rows cannot be trusted
        why = problems.pop("/")
        problems.update({f"{d.name}#": why for d in datasets})
    out = {}
    for dataset, sink, rows in zip(datasets, sinks, held):
        name = dataset.name
        got = np.frombuffer(sink, dataset.dtype, count=rows).copy()
        sink.close()
        keep = np.full(rows, not ({f"{name}#", f"{name}#shape"} & set(problems)))
        step = block_rows(dataset.shape, dataset.chunks)
        for first in {int(k[len(name) + 1:]) for k in problems if k.startswith(name + "#") and k[len(name) + 1:].isdigit()}:
            keep[first:first + step] = False
        out[name] = got[keep]
    check = dataclasses.replace(check, problems=problems, runs=check.runs + runs, seconds=check.seconds +
                                time.perf_counter() - start, rows_read=check.rows_read | {d.name for d in datasets})
    return check, out


def _open_here(path: Path) -> bool:
    """Is ``path`` open for writing in this process (the session being recorded)? libhdf5 then reads it from what it
    holds in memory, and a child must not touch that file's state."""
    try:
        target = path.resolve()
        for fid in h5py.h5f.get_obj_ids(h5py.h5f.OBJ_ALL, h5py.h5f.OBJ_FILE):
            if fid.get_intent() & h5py.h5f.ACC_RDWR and Path(os.fsdecode(fid.name)).resolve() == target:
                return True
    except (OSError, ValueError, RuntimeError, TypeError, AttributeError):
        pass
    return False


