"""The forked children that read a possibly damaged HDF5 file for :mod:`.filecheck`, and the parent's watch on them.

Why apart: this is the mechanism (what a child reads, how it names each key in shared memory before touching it, how
the parent sees it crash or stall and starts the next one leaving that key out); :mod:`.filecheck` says what was
found. Also here: the chunk arithmetic both sides share (rows a dataset really holds, rows a block holds).
"""

from __future__ import annotations

import faulthandler
import gc
import json
import mmap
import os
import pickle
import select
import signal
import struct
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import h5py

__all__ = ["Job", "children", "run_child", "walk_chunk_index", "held_rows", "block_rows", "STALL_S", "MAX_RUNS"]

_WHOLE = 1 << 20       # a contiguous dataset up to this many elements is read whole; larger ones by blocks of rows
_LOCKED = "unable to lock file"
_LOG_BYTES = 64 << 20  # shared memory for the child's messages (touched only as far as written)
_POLL_S = 0.2
_MAX_RATIO = 1000     # no compressed chunk holds more than this many times its bytes (gzip of zeros: ~1000)
_BLOCK_CHUNKS = 16     # chunks read at once: fewer calls into h5py; a block that fails is read again chunk by chunk
STALL_S = 10.0         # a child that reports nothing for this long is stuck in libhdf5 (a B-tree that loops)
MAX_RUNS = 24          # children per file: each run leaves out one more object that crashed or hung the last one


def walk_chunk_index(dataset: h5py.Dataset) -> int:
    """Walk the chunk index (where each chunk lies in the file) without reading a chunk; the number of chunks."""
    found = []
    if hasattr(dataset.id, "chunk_iter"):
        dataset.id.chunk_iter(found.append)
    else:                                                   # libhdf5 before 1.14: one lookup per chunk
        found = [dataset.id.get_chunk_info(k) for k in range(dataset.id.get_num_chunks())]
    return len(found)


def held_rows(dataset: h5py.Dataset) -> int:
    """The rows a dataset really holds: its shape, but no more than its chunks (or its contiguous storage) cover, so a
    damaged shape claiming 2^60 rows is not believed (reading or allocating them would never end)."""
    rows = int(dataset.shape[0]) if dataset.shape else 1
    if dataset.chunks:
        starts = []
        try:
            if hasattr(dataset.id, "chunk_iter"):
                dataset.id.chunk_iter(lambda info: starts.append(info.chunk_offset[0]))
            else:                                           # libhdf5 before 1.14: one lookup per chunk
                starts += [dataset.id.get_chunk_info(k).chunk_offset[0] for k in range(dataset.id.get_num_chunks())]
        except (RuntimeError, OSError, ValueError):         # a damaged index: believe the shape, within reason
            row_bytes = max(1, dataset.dtype.itemsize * _size(dataset.shape[1:]))
            return min(rows, _MAX_RATIO * os.path.getsize(dataset.file.filename) // row_bytes)
        return min(rows, max(starts) + dataset.chunks[0]) if starts else 0
    row_bytes = max(1, dataset.dtype.itemsize * _size(dataset.shape[1:]))
    return min(rows, dataset.id.get_storage_size() // row_bytes)



@dataclass(frozen=True)
class Job:
    """What a child reads: the whole file (rows under ``defer`` left out), or only the rows of the datasets in
    ``only`` (open handles of this process), each copied into its sink (shared memory) at their place."""

    only: tuple = ()                             # (dataset, sink) pairs
    defer: tuple[str, ...] = ()
    read: object = None                          # a function of the open file, run whole (read_checked)
    sink: mmap.mmap | None = None                # where read's value goes, pickled


def children(path: Path, problems: dict[str, str], job: Job, stall_s: float):
    """Children until one finishes, each leaving out what crashed or hung the one before: (problems, runs)."""
    refine: set[str] = set()           # blocks of rows that crashed a child: the next reads them chunk by chunk
    runs = 0
    while True:
        runs += 1
        finished, current, cause = run_child(path, set(problems) | refine, problems, stall_s, job)
        if finished:
            return problems, runs
        if current is None or runs >= MAX_RUNS:
            problems["/"] = problems.get("/") or (cause or "libhdf5 could not read it")
            return problems, runs
        if "-" in current.rpartition("#")[2]:
            refine.add(current)
        else:
            problems[current] = cause



def run_child(path: Path, skip: set[str], problems: dict[str, str], stall_s: float, job: Job):
    """One child: (finished, the key it was reading when it stopped, why it stopped). The child logs to shared memory
    (no system call per key); a pipe only tells when it has ended."""
    log = mmap.mmap(-1, _LOG_BYTES)
    read_end, write_end = os.pipe()
    with warnings.catch_warnings():          # Python >= 3.12 warns about fork in a process with threads; h5py resets
        warnings.simplefilter("ignore", DeprecationWarning)   # its own lock at fork, and the child uses nothing else
        pid = os.fork()
    if pid == 0:                                                        # the child
        os.close(read_end)
        code = 0
        try:
            _child(path, skip, _Log(log), job)
        except BaseException:                                           # noqa: BLE001 - the child must only exit
            code = 1
        os._exit(code)
    os.close(write_end)
    cause, seen, last_progress = "", -1, time.monotonic()
    try:
        while not select.select([read_end], [], [], _POLL_S)[0]:
            written = _Log.length(log)
            if written != seen:
                seen, last_progress = written, time.monotonic()
            elif time.monotonic() - last_progress > stall_s:
                cause = f"libhdf5 makes no progress reading it ({stall_s:g} s)"
                os.kill(pid, signal.SIGKILL)
                break
    except BaseException:
        os.kill(pid, signal.SIGKILL)
        raise
    finally:
        os.close(read_end)
        _, status = os.waitpid(pid, 0)
    current, finished = None, False
    for message in _Log.messages(log):
        if message[0] == "start":
            current = message[1]
        elif message[0] == "ok":
            current = None
        elif message[0] == "error":
            problems[message[1]] = message[2]
            current = None
        elif message[0] == "done":
            finished = True
    log.close()
    if not finished and not cause:
        cause = (f"reading it crashes libhdf5 (signal {os.WTERMSIG(status)})" if os.WIFSIGNALED(status)
                 else "reading it stopped the reader")
    return finished, current, cause


class _Log:
    """Messages appended to shared memory: each record is written whole before the length in front is moved past
    it, so a child killed in the middle of a record leaves the ones before it readable."""

    def __init__(self, memory: mmap.mmap):
        self._memory, self._end = memory, 8

    def write(self, message) -> None:
        data = json.dumps(message).encode("utf-8") + b"\n"
        if self._end + len(data) > len(self._memory):
            raise MemoryError("file check log full")
        self._memory[self._end:self._end + len(data)] = data
        self._end += len(data)
        struct.pack_into("<Q", self._memory, 0, self._end)

    @staticmethod
    def length(memory: mmap.mmap) -> int:
        return struct.unpack_from("<Q", memory, 0)[0]

    @staticmethod
    def messages(memory: mmap.mmap):
        end = _Log.length(memory)
        return [json.loads(line) for line in memory[8:end].split(b"\n") if line]


def _child(path: Path, skip: set[str], log: _Log, job: Job) -> None:
    """Read what ``job`` says except what is in ``skip``, naming each key before touching it (``start``) and after
    (``ok``/``error``)."""
    gc.disable()            # objects inherited from the parent (its open files) must never be finalised here
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    faulthandler.disable()  # a crash here is expected and reported by the parent, not dumped on the user's terminal
    quiet = os.open(os.devnull, os.O_WRONLY)
    os.dup2(quiet, 2)

    def say(*message) -> None:
        log.write(message)

    def attempt(key: str, read, quiet: bool = False):
        if key in skip:
            return None
        say("start", key)
        try:
            value = read()
        except Exception as err:                                        # noqa: BLE001 - any failure marks the key
            say("ok" if quiet else "error", key, _reason(err))          # quiet: the caller looks closer itself
            return None
        say("ok", key)
        return value if value is not None else True

    def walk(obj, name: str) -> None:
        names = attempt(f"{name}@*", lambda: list(obj.attrs))
        for attribute in names if isinstance(names, list) else ():
            attempt(f"{name}@{attribute}", lambda a=attribute: obj.attrs[a])
        if isinstance(obj, h5py.Group):
            members = attempt(f"{name.rstrip('/')}/*", lambda: list(obj.keys()))
            for member in members if isinstance(members, list) else ():
                child = f"{name.rstrip('/')}/{member}"
                sub = attempt(child, lambda m=member: obj[m])
                if sub not in (None, True):
                    walk(sub, child)
        elif isinstance(obj, h5py.Dataset):
            _read_dataset(obj, name, attempt, skip, rows=not name.startswith(job.defer))

    if job.read is not None:
        with h5py.File(path, "r") as h5:
            data = pickle.dumps(job.read(h5), protocol=pickle.HIGHEST_PROTOCOL)
        if 8 + len(data) <= len(job.sink):
            job.sink[8:8 + len(data)] = data
            struct.pack_into("<Q", job.sink, 0, len(data))
        say("done")
        return
    if job.only:
        for dataset, sink in job.only:
            _read_dataset(dataset, dataset.name, attempt, skip, rows=True, sink=sink)
        say("done")
        return
    if "/" in skip:
        say("done")
        return
    say("start", "/")
    try:
        h5 = h5py.File(path, "r")
    except Exception as err:                                            # noqa: BLE001
        say("error", "/", _open_reason(err))
        say("done")
        return
    say("ok", "/")
    walk(h5, "/")
    say("done")


def _read_dataset(dataset: h5py.Dataset, name: str, attempt, skip: set[str], rows: bool, sink=None) -> None:
    """Every row of a dataset: whole when small and contiguous, else in blocks of ``_BLOCK_CHUNKS`` chunks; a block
    that fails (or crashed a child before) is read again chunk by chunk, so only its bad chunks are lost. Without
    ``rows``, only the shape and the chunk index (where each chunk lies) are read. With a ``sink`` (shared memory),
    the rows read are copied into it at their place."""
    shape = attempt(f"{name}#shape", lambda: (dataset.shape, dataset.chunks, dataset.dtype))
    if not isinstance(shape, tuple):
        return
    dims, chunks, _ = shape
    if not rows:
        if chunks is not None:
            attempt(f"{name}#index", lambda: walk_chunk_index(dataset))
        return

    def take(first: int, end: int | None):
        values = dataset[()] if end is None else dataset[first:end]
        if sink is not None:
            data = values.tobytes()
            offset = first * dataset.dtype.itemsize
            sink[offset:offset + len(data)] = data
        return True

    if not dims or (chunks is None and int(_size(dims)) <= _WHOLE) or dims[0] == 0:
        attempt(f"{name}#", lambda: take(0, None))
        return
    rows = attempt(f"{name}#extent", lambda: held_rows(dataset))
    if not isinstance(rows, int) or isinstance(rows, bool):
        return
    step = block_rows(dims, chunks)
    block = step * _BLOCK_CHUNKS
    for first in range(0, rows, block):
        end = min(first + block, rows)
        coarse = f"{name}#{first}-{end}"
        if coarse not in skip and attempt(coarse, lambda f=first, e=end: take(f, e), quiet=True) is not None:
            continue
        for start in range(first, end, step):
            attempt(f"{name}#{start}", lambda f=start: take(f, min(f + step, rows)))


def block_rows(shape: tuple, chunks: tuple | None) -> int:
    """The rows of one block, the unit in which damage is found: a chunk, or a slice of a contiguous dataset."""
    return int(chunks[0]) if chunks else max(1, _WHOLE // max(1, _size(shape[1:])))


def _size(dims) -> int:
    n = 1
    for d in dims:
        n *= int(d)
    return n


def _reason(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text[:200]


def _open_reason(err: BaseException) -> str:
    text = str(err)
    if _LOCKED in text:
        return "it is open for writing in another program (being recorded?)"
    if isinstance(err, PermissionError) or "Permission denied" in text or "errno = 13" in text:
        return "no permission to read it"
    if "file signature not found" in text or "not an HDF5 file" in text.lower():
        return "it is not an HDF5 file"
    return f"libhdf5 cannot open it ({_reason(err)})"
