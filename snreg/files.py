"""Files: inputs read with one clear error (regular files only; OpenCV ``FileStorage`` files as plain values), and
every output written atomically.

Why atomic: a full disk or a crash while writing must never leave a fragment where the user expects a
calibration, a node file or a report, nor destroy the previous version. :func:`atomic_write` hands out a
temporary name in the target's own folder (so the final rename stays on one file system) and renames it
over the target only once everything is written and synced.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

__all__ = ["read_storage", "StorageValues", "atomic_write", "require_regular_file", "read_text_file", "read_image",
           "MAX_TEXT_BYTES"]

MAX_TEXT_BYTES = 64 << 20      # node files, calibrations, transforms, tables: far smaller; a larger one is a mistake

_UMASK = os.umask(0o022)
os.umask(_UMASK)             # read once: new outputs get the usual permissions, not mkstemp's 0600


def require_regular_file(path: str | Path, what: str, error: type[Exception] = ValueError) -> Path:
    """``path`` if it is a regular file; else ``error`` in one sentence: missing, a folder, or something that is not
    a file at all (a pipe would block the reader, a device such as /dev/zero would never end)."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise error(f"{path}: no such {what} file") from None
    except OSError as err:
        raise error(f"{path}: cannot read the {what} file ({err.strerror or err})") from None
    if stat.S_ISDIR(mode):
        raise error(f"{path} is a folder; give {_a(what)} file")
    if not stat.S_ISREG(mode):
        raise error(f"{path}: not a regular file (a device, pipe or socket); give {_a(what)} file")
    return path


def read_image(path: str | Path, flags: int | None = None, error: type[Exception] = ValueError):
    """An image file read by ``cv2.imread`` (BGR by default); ``error`` when it is not a regular file or no image."""
    import cv2

    require_regular_file(path, "image", error)
    try:
        image = cv2.imread(str(path), cv2.IMREAD_COLOR if flags is None else flags)
    except cv2.error:                  # e.g. a header claiming more pixels than OpenCV's limit (2^30)
        image = None
    if image is None:
        raise error(f"{path}: not a readable image")
    return image


def _a(what: str) -> str:
    return f"{'an' if what[:1].lower() in 'aeiou' else 'a'} {what}"


def read_text_file(path: str | Path, what: str, error: type[Exception] = ValueError, *,
                   max_bytes: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of a regular file (a byte-order mark dropped); ``error`` in one sentence when it is not one, is
    larger than ``max_bytes``, cannot be read or is not UTF-8 text."""
    path = require_regular_file(path, what, error)
    try:
        with open(path, "rb") as file:
            raw = file.read(max_bytes + 1)
    except OSError as err:
        raise error(f"{path}: cannot read the {what} file ({err.strerror or err})") from None
    if len(raw) > max_bytes:
        raise error(f"{path}: larger than {max_bytes >> 20} MB; that is not {_a(what)} file")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise error(f"{path}: not a text {what} file (expected UTF-8)") from None


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


# -- OpenCV FileStorage files ----------------------------------------------------------------------------------
# OpenCV's parser recurses once per nesting level (a file nested some tens of thousands of levels deep ends the
# process with a segmentation fault), blocks on a pipe, reads /dev/zero until memory runs out and answers a malformed
# matrix with a C++ assertion: so the file must be a regular text file of sane size and nesting before OpenCV sees
# it, and every value is taken out one key at a time, a matrix that does not parse named with what is wrong with it.

MAX_STORAGE_BYTES = 16 << 20     # a calibration is a few kB
MAX_NESTING = 64                 # a calibration nests two levels deep (a matrix in the root map)
ISOLATED_TIMEOUT_S = 10.0        # parsing a FileStorage file of at most MAX_STORAGE_BYTES takes well under a second
_INDENT = re.compile(r"^[ \t]*", re.MULTILINE)


@dataclass
class StorageValues:
    """The root keys in file order and their values: ``matrices`` (numpy arrays), ``numbers`` (float), ``texts``;
    ``broken`` maps a key whose value could not be read to why."""

    keys: tuple[str, ...]
    matrices: dict[str, np.ndarray] = field(default_factory=dict)
    numbers: dict[str, float] = field(default_factory=dict)
    texts: dict[str, str] = field(default_factory=dict)
    broken: dict[str, str] = field(default_factory=dict)

    def kind(self, key: str) -> str:
        """What the file holds under ``key``, in words (for messages)."""
        if key in self.matrices:
            return "a matrix"
        if key in self.numbers:
            return f"the number {self.numbers[key]:g}"
        if key in self.texts:
            return f"the text {self.texts[key]!r}"
        return self.broken.get(key, "nothing")


def read_storage(path: str | Path, what: str, error: type[Exception]) -> StorageValues:
    """Every root value of the FileStorage file ``path``; ``error`` in one sentence naming ``what`` when the file is
    not one (missing, not a regular file, too large, too deeply nested, unparsable, without a root map)."""
    path = Path(path)
    source, flags = _storage_source(path, what, error)
    outcome = _isolated(lambda: _parse(source, flags, what))
    if outcome is None:
        raise error(f"{path}: OpenCV's parser failed on it (it crashed or never ended); not an OpenCV {what} file")
    if isinstance(outcome, str):
        raise error(f"{path}: {outcome}")
    return outcome


def read_storage_with(path: str | Path, what: str, error: type[Exception], read):
    """``read(fs)`` on the FileStorage file ``path`` (checked as :func:`read_storage` checks it), run in a forked
    child, for files whose values nest deeper than a root map; a ValueError ``read`` raises becomes ``error`` with its
    message, and so does a parse that fails or crashes."""
    import cv2

    path = Path(path)
    source, flags = _storage_source(path, what, error)
    not_one = f"{path}: not an OpenCV {what} file (YAML/XML FileStorage)"

    def work():
        try:
            fs = cv2.FileStorage(source, flags)
        except (cv2.error, SystemError):
            return "error", not_one
        try:
            return ("ok", read(fs)) if fs.isOpened() else ("error", not_one)
        except ValueError as err:
            return "error", str(err)
        except (cv2.error, SystemError):
            return "error", not_one
        finally:
            fs.release()

    outcome = _isolated(work)
    if outcome is None:
        raise error(f"{path}: OpenCV's parser failed on it (it crashed or never ended); not an OpenCV {what} file")
    if outcome[0] == "error":
        raise error(outcome[1])
    return outcome[1]


def _storage_source(path: Path, what: str, error: type[Exception]) -> tuple[str, int]:
    """(text or path, flags) for ``cv2.FileStorage``: a regular file of sane size and nesting, or ``error``."""
    import cv2  # only the FileStorage readers need OpenCV; atomic_write must stay light

    if path.suffix.lower() == ".gz":                       # compressed: OpenCV reads it from the path itself
        return str(require_regular_file(path, what, error)), cv2.FILE_STORAGE_READ
    text = read_text_file(path, what, error, max_bytes=MAX_STORAGE_BYTES)
    depth = _nesting(text)
    if depth > MAX_NESTING:
        raise error(f"{path}: nested {depth} levels deep; not an OpenCV {what} file")
    if not text.strip():
        raise error(f"{path}: empty; not an OpenCV {what} file (YAML/XML FileStorage)")
    return text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY


def _parse(source: str, flags: int, what: str) -> StorageValues | str:
    """The root values of a FileStorage text (or path), or why it is not one (a phrase)."""
    import cv2

    not_one = f"not an OpenCV {what} file (YAML/XML FileStorage)"
    try:
        fs = cv2.FileStorage(source, flags)
    except (cv2.error, SystemError):                   # OpenCV 5 wraps its parse error in a SystemError
        return not_one
    try:
        if not fs.isOpened():
            return not_one
        root = fs.root()
        if root.empty() or not root.isMap():
            return f"holds no keys (an empty file, or only a header); not an OpenCV {what} file"
        values = StorageValues(tuple(root.keys()))
        for key in values.keys:
            _take(fs.getNode(key), key, values)
        return values
    except (cv2.error, SystemError):
        return not_one
    finally:
        fs.release()


def _isolated(work, timeout_s: float = ISOLATED_TIMEOUT_S):
    """``work()`` run in a forked child and its (pickled) value handed back, so that a crash of the C++ code it calls
    (OpenCV's parser has aborted on rare malformed files) ends the child, not this process: None then. A child that
    never ends is killed after ``timeout_s``, and ``work`` is run here instead (a lock held by another thread of this
    process at the fork could be what stopped it). Without fork, ``work`` runs here."""
    import pickle
    import select
    import signal
    import warnings

    if not hasattr(os, "fork"):
        return work()
    read_end, write_end = os.pipe()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)        # Python >= 3.12 on fork with threads
        pid = os.fork()
    if pid == 0:
        os.close(read_end)
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), 2)
            data = pickle.dumps(work())
            while data:
                data = data[os.write(write_end, data):]
        finally:
            os._exit(0)
    os.close(write_end)
    chunks, ended = [], True
    try:
        while True:
            if not select.select([read_end], [], [], timeout_s)[0]:
                ended = False
                os.kill(pid, signal.SIGKILL)
                break
            chunk = os.read(read_end, 1 << 20)
            if not chunk:
                break
            chunks.append(chunk)
    finally:
        os.close(read_end)
        _, status = os.waitpid(pid, 0)
    if not ended:
        return work()
    if os.WIFSIGNALED(status) or not chunks:
        return None
    return pickle.loads(b"".join(chunks))


def _take(node, key: str, values: StorageValues) -> None:
    """Put one root value where it belongs in ``values``."""
    import cv2
    import numpy as np

    try:
        if node.isInt() or node.isReal():
            values.numbers[key] = float(node.real())
        elif node.isString():
            values.texts[key] = node.string()
        elif node.isMap():
            matrix = node.mat()
            if matrix is None:
                values.broken[key] = "a map, not an opencv-matrix"
            else:
                values.matrices[key] = np.asarray(matrix, dtype=float)
        elif node.isSeq():
            values.broken[key] = "a list, not an opencv-matrix (rows, cols, dt, data)"
        else:
            values.broken[key] = "empty"
    except (cv2.error, SystemError) as err:
        values.broken[key] = _matrix_fault(str(err))


def _matrix_fault(message: str) -> str:
    if "nelems" in message:
        return "an opencv-matrix whose data holds more or fewer values than rows x cols (cut short?)"
    if "dt.empty" in message or "sizes_node" in message or "isMap" in message:
        return "a map, not a complete opencv-matrix (rows, cols, dt and data)"
    if "symbolToType" in message or "type specification" in message:
        return "an opencv-matrix with an unknown data type (dt)"
    if "Insufficient memory" in message or "Failed to allocate" in message:
        return "an opencv-matrix too large to hold"
    return "an opencv-matrix that OpenCV cannot read"


def _nesting(text: str) -> int:
    """The deepest nesting of brackets, braces or XML elements, or indentation (in characters), whichever is larger."""
    depth = deepest = 0
    for char in re.sub(r"\"[^\"\n]*\"|'[^'\n]*'", "", text):
        if char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth = max(0, depth - 1)
    xml = deepest_xml = 0
    for closing, _, empty in re.findall(r"<(/?)([A-Za-z_][\w.-]*)[^<>]*?(/?)>", text):
        if closing:
            xml = max(0, xml - 1)
        elif not empty:
            xml += 1
            deepest_xml = max(deepest_xml, xml)
    indent = max((len(m) for m in _INDENT.findall(text)), default=0) // 2
    return max(deepest, deepest_xml, indent)
