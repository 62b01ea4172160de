"""Files: OpenCV ``FileStorage`` files opened with one clear error, and every output written atomically.

Why atomic: a full disk or a crash while writing must never leave a fragment where the user expects a
calibration, a node file or a report, nor destroy the previous version. :func:`atomic_write` hands out a
temporary name in the target's own folder (so the final rename stays on one file system) and renames it
over the target only once everything is written and synced.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

__all__ = ["open_for_reading", "atomic_write"]

_UMASK = os.umask(0o022)
os.umask(_UMASK)             # read once: new outputs get the usual permissions, not mkstemp's 0600


def open_for_reading(path: str | Path, what: str, error: type[Exception] = ValueError):
    """Open ``path`` as a ``cv2.FileStorage`` for reading; raise ``error`` naming ``what`` when it is missing or not such a file."""
    import cv2  # only the FileStorage readers need OpenCV; atomic_write must stay light

    path = Path(path)
    if not path.is_file():
        raise error(f"{path}: no such {what} file")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError):   # OpenCV 5 wraps its parse error in a SystemError
        raise error(f"{path}: not an OpenCV {what} file (YAML/XML FileStorage)") from None
    if not fs.isOpened():
        raise error(f"{path}: not an OpenCV {what} file (YAML/XML FileStorage)")
    return fs


@contextlib.contextmanager
def atomic_write(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s content to; on success it replaces ``path`` in one rename.

    The temporary file sits beside the target as ``.<stem>.<random>.tmp<suffixes>`` (hidden, and with the
    target's suffixes, so writers that choose a format by extension, e.g. ``cv2.FileStorage`` or
    matplotlib, still do). It is fsynced before the rename; if the block raises, the temporary file is
    removed and the target is untouched. A target that exists and is not a regular file (``/dev/stdout``,
    ``/dev/full``, a FIFO) is never replaced: the content is copied into it, so its write errors surface.
    Raises ``OSError`` (e.g. missing folder, no space left); callers turn it into a one-sentence message.
    """
    path = Path(path)
    special = path.exists() and not stat.S_ISREG(path.stat().st_mode) and not path.is_dir()
    folder = None if special else path.parent
    suffixes = "".join(path.suffixes[-2:])
    stem = path.name[:len(path.name) - len(suffixes)] if suffixes else path.name
    handle, name = tempfile.mkstemp(prefix=f".{stem}.", suffix=f".tmp{suffixes}", dir=folder)
    os.close(handle)
    temporary = Path(name)
    try:
        yield temporary
        if special:
            with open(temporary, "rb") as source, open(path, "wb") as target:
                shutil.copyfileobj(source, target)
                target.flush()
        else:
            with open(temporary, "rb+") as written:
                os.fsync(written.fileno())
            mode = stat.S_IMODE(path.stat().st_mode) if path.is_file() else 0o666 & ~_UMASK
            os.chmod(temporary, mode)
            os.replace(temporary, path)
    finally:
        with contextlib.suppress(FileNotFoundError):
            temporary.unlink()
