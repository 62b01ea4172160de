"""The headless demo records into a hidden folder beside its output and moves the files out only when it completes.

Why: a demo that fails (or is killed) half-way must not leave ``-o SESSION.h5`` behind, or the retry with the same
command is refused ("already exists"). Yet the session keeps DESIGN's crash-safety contract while it records: it is an
ordinary session (HDF5 + journal, videos named from its stem) in ``.SESSION.h5.partial-XXXX/`` in the same folder, so a
kill leaves every stored node readable there (``snreg session info .SESSION.h5.partial-XXXX/SESSION.h5``), on the same
file system as the output, so publishing is one rename per file. The session keeps its own name inside the folder:
its videos are listed by file name beside it, and stay right after the move.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from snreg.session.journal import fsync_directory

__all__ = ["staging_folder", "publish", "discard"]


def staging_folder(target: str | Path) -> Path:
    """A new hidden folder beside ``target`` to record into (a new one each run: a killed run's stays as it was)."""
    target = Path(target)
    return Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=target.parent))


def publish(folder: Path, target: str | Path, replaceable: tuple[str, ...] = ()) -> None:
    """Move every file of ``folder`` beside ``target`` (same names), then remove the folder. Files named in
    ``replaceable`` may replace an existing one; any other that exists is refused with OSError before anything moves
    (the staged run is then left where it is)."""
    target = Path(target)
    names = sorted(p.name for p in folder.iterdir())
    taken = [name for name in names if name not in replaceable and (target.parent / name).exists()]
    if taken:
        raise OSError(f"{target.parent / taken[0]} appeared while the demo ran; the run is kept in {folder}: move "
                      "its files out by hand or run again with a new -o")
    # the session last: until it is out, the output name is free and the run can be found in the folder
    for name in sorted(names, key=lambda n: n == target.name):
        os.replace(folder / name, target.parent / name)
    fsync_directory(target.parent)
    folder.rmdir()


def discard(folder: Path) -> None:
    """Remove a staged run and everything in it (a run that failed and is not kept)."""
    shutil.rmtree(folder, ignore_errors=True)
