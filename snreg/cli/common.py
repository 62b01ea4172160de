"""What the ``snreg`` subcommands share: the parser class, argument types, output checks and writes, progress.

Why here: every subcommand must fail the same way (one line on stderr, exit status 2, nothing written), and
building the parser must stay cheap (``snreg --help``), so this module imports nothing heavy at the top;
numpy and the rest are imported by the functions that need them.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import math
import os
import re
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

from snreg.errors import UserError
from snreg.files import atomic_write

__all__ = ["Parser", "floats", "ints", "positive_int", "non_negative_int", "int_range", "float_range", "workers", "seed",
           "positive_float", "finite_float", "down_vector",
           "fraction", "image_size", "depth_range", "check_output_file", "check_output_folder", "writing", "write_text",
           "read_initial", "session_initial", "progress"]


class _HelpFormatter(argparse.HelpFormatter):
    """argparse's help, with each option's default appended where it has one worth showing."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if (default in (None, False, argparse.SUPPRESS) or "default" in text.lower() or not action.option_strings
                or isinstance(action, (argparse._HelpAction, argparse._VersionAction))):
            return text
        shown = ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in default) \
            if isinstance(default, (tuple, list)) else default
        return f"{text} (default: {str(shown).replace('%', '%%')})"


class Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line on stderr (``snreg <command>: ...``) with exit status 2, and
    whose help shows the defaults; subcommand parsers inherit both."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", _HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        text = " ".join(message.split())
        self.exit(2, f"{self.prog}: {text}; see '{self.prog} --help'\n")


# -- argument types (argparse names the option in front of the message) ---------------------------------------

def floats(text: str) -> tuple[float, ...]:
    """Comma-separated finite numbers."""
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected finite numbers, got {text!r}")
    return values


def ints(text: str) -> tuple[int, ...]:
    """Comma-separated integers."""
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def _integer(text: str, low: int, what: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
    return value


def positive_int(text: str) -> int:
    return _integer(text, 1, "a whole number of at least 1")


def int_range(low: int, high: int, unit: str = ""):
    """An argument type: a whole number from ``low`` to ``high`` (both included)."""
    what = f"a whole number from {low} to {high}{' ' + unit if unit else ''}"

    def parse(text: str) -> int:
        value = _integer(text, low, what)
        if value > high:
            raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
        return value
    return parse


def float_range(low: float, high: float, unit: str = "", *, low_open: bool = True):
    """An argument type: a finite number in ``(low, high]`` (``[low, high]`` when not ``low_open``)."""
    what = f"a number {'above' if low_open else 'from'} {low:g} {'and at most' if low_open else 'to'} {high:g}" + \
        (f" {unit}" if unit else "")

    def parse(text: str) -> float:
        value = finite_float(text)
        if not ((value > low) if low_open else (value >= low)) or value > high:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value
    return parse


def workers(text: str) -> int:
    """Worker processes: 0 (one per CPU) up to the CPUs this machine has."""
    cpus = os.cpu_count() or 1
    return int_range(0, cpus, f"(0: one per CPU; this machine has {cpus})")(text)


def non_negative_int(text: str) -> int:
    return _integer(text, 0, "a whole number of at least 0")


def seed(text: str) -> int:
    """A random seed: 0 to 2**32 - 1 (what numpy and every seeded process here accept)."""
    value = _integer(text, 0, "a seed from 0 to 4294967295")
    if value >= 2**32:
        raise argparse.ArgumentTypeError(f"expected a seed from 0 to 4294967295, got {value}")
    return value


def finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def positive_float(text: str) -> float:
    value = finite_float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def fraction(text: str) -> float:
    """A number from 0 to 1."""
    value = finite_float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a fraction from 0 to 1, got {text!r}")
    return value


def down_vector(text: str) -> tuple[float, float, float]:
    """``X,Y,Z``: gravity's direction in a frame, three finite numbers not all zero (any length: only the direction
    counts)."""
    values = floats(text)
    if len(values) != 3 or not any(values):
        raise argparse.ArgumentTypeError(f"expected a direction X,Y,Z pointing down: three finite numbers, not all zero "
                                         f"(e.g. 0,1,0), got {text!r}")
    return values


def image_size(text: str) -> tuple[int, int]:
    """``WxH`` in pixels, e.g. ``1920x1080``."""
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not match or int(match[1]) < 1 or int(match[2]) < 1:
        raise argparse.ArgumentTypeError(f"expected the image size as WxH pixels, e.g. 1920x1080, got {text!r}")
    return int(match[1]), int(match[2])


def depth_range(text: str) -> tuple[float, float]:
    """``MIN,MAX`` mm in front of the camera, ``0 < MIN < MAX``."""
    values = floats(text)
    if len(values) != 2 or not 0 < values[0] < values[1]:
        raise argparse.ArgumentTypeError(f"expected MIN,MAX mm with 0 < MIN < MAX, e.g. 20,300, got {text!r}")
    return values


# -- outputs --------------------------------------------------------------------------------------------------

def check_output_file(path: str | os.PathLike, what: str, *, new: bool = False) -> Path:
    """Refuse, before any work, an output file that cannot be written: missing folder, a folder, an existing
    file where ``new`` asks for a new one, a folder without write permission."""
    path = Path(path)
    folder = path.parent
    if path.is_dir():
        raise UserError(f"{path} is a folder; give a file name for the {what}")
    if not folder.is_dir():
        raise UserError(f"{path}: the folder {folder} does not exist; create it or write the {what} elsewhere")
    if new and path.exists():
        raise UserError(f"{path} already exists; give a new name for the {what} (nothing was overwritten)")
    if path.exists() and not os.access(path, os.W_OK):
        raise UserError(f"{path}: no permission to replace it; write the {what} elsewhere")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise UserError(f"{path}: no permission to write in {folder}; write the {what} elsewhere")
    return path


def check_output_folder(path: str | os.PathLike, what: str) -> Path:
    """Refuse, before any work, an output folder that cannot be made or written to (an existing folder is fine)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UserError(f"{path} is a file, not a folder; give a folder name for the {what}")
    if not path.exists():
        if not path.parent.is_dir():
            raise UserError(f"{path}: the folder {path.parent} does not exist; create it or choose another place for the {what}")
        if not os.access(path.parent, os.W_OK | os.X_OK):
            raise UserError(f"{path}: no permission to create it in {path.parent}; choose another place for the {what}")
    elif not os.access(path, os.W_OK | os.X_OK):
        raise UserError(f"{path}: no permission to write in it; choose another place for the {what}")
    return path


@contextlib.contextmanager
def writing(path: str | os.PathLike, what: str) -> Iterator[Path]:
    """:func:`snreg.files.atomic_write` whose ``OSError`` (full disk, missing folder) is a one-sentence ``UserError``."""
    try:
        with atomic_write(path) as temporary:
            yield temporary
    except OSError as err:
        raise UserError(f"{path}: cannot write the {what} ({err.strerror or err}); nothing was written") from None


def write_text(path: str | os.PathLike, text: str, what: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically; a one-sentence ``UserError`` if it cannot be."""
    with writing(path, what) as temporary:
        temporary.write_text(text, encoding="utf-8")


# -- inputs ---------------------------------------------------------------------------------------------------

def read_initial(path: str | None):
    """A 4x4 ``intraop_from_preop`` (numpy array) from a text or JSON file (``{"transform": ...}`` or a bare
    matrix), or the initial alignment stored with a session's last registration (``.h5``); None if no path.
    Any other content is a one-sentence ``UserError``."""
    if path is None:
        return None
    if Path(path).suffix.lower() in (".h5", ".hdf5"):
        return session_initial(path)
    import json

    import numpy as np

    from snreg.files import read_text_file

    expected = 'expected a 4x4 matrix as text rows or JSON (a list of 4 rows, or {"transform": [[...], ...]})'
    text = read_text_file(path, "initial transform", UserError, max_bytes=1 << 20)
    try:
        if path.lower().endswith(".json"):
            data = json.loads(text)
            if isinstance(data, dict):
                if "transform" not in data:
                    raise UserError(f"{path}: the JSON object has no \"transform\" (it has {', '.join(map(str, data)) or 'no keys'}); "
                                    + expected)
                data = data["transform"]
        else:
            data = np.loadtxt(text.splitlines(), delimiter="," if "," in text else None, ndmin=2)
        matrix = np.asarray(data, dtype=float)
    except (ValueError, TypeError, OverflowError, RecursionError):
        raise UserError(f"{path}: not a matrix of numbers; {expected}") from None
    if matrix.shape != (4, 4):
        raise UserError(f"{path}: the initial transform must be 4x4, got shape {matrix.shape}; {expected}")
    if not np.isfinite(matrix).all():
        raise UserError(f"{path}: the initial transform holds NaN or infinite values")
    return matrix


def session_initial(path: str):
    """The initial alignment stored with the session's last registration that kept one."""
    from snreg.errors import SessionError
    from snreg.session import Session  # h5py only when a session is read

    try:
        with Session.open(path) as session:
            initial = session.last_initial()
    except (SessionError, OSError) as err:
        raise UserError(str(err)) from None
    if initial is None:
        raise UserError(f"{path}: no registration in this session kept its initial alignment; give --initial as a "
                        "4x4 text or JSON file")
    return initial


def progress(label: str, always: bool = False) -> Callable[[int, int], None]:
    """A ``(done, total)`` callback that keeps one updating line on stderr: on a terminal, or ``always``."""
    show = always or sys.stderr.isatty()

    def report(done: int, total: int) -> None:
        if show:
            print(f"\r{label}: {done}/{total}", end="" if done < total else "\n", file=sys.stderr, flush=True)

    return report


def folder_pairs(source, label: str):
    """The (left, right) images of an opened-on-use image folder ``source`` (:class:`~snreg.sources.ImageFolderSource`),
    in order, with a progress line ``label``; a pair that cannot be read ends it with a one-sentence UserError."""
    report = progress(label)
    with source:
        for k in range(len(source)):
            frame = source.read()
            if frame is None:
                raise UserError(source.problem or f"pair {k} could not be read")
            report(k + 1, len(source))
            yield frame.left, frame.right


def read_orientations(path: str, count: int, per: str):
    """``earth_from_imu`` per ``per`` (image, pair: ``count`` of them) as a scipy ``Rotation`` from a CSV with
    ``yaw``, ``pitch``, ``roll`` columns (degrees, docs/design.md (Conventions): ZYX; ``#`` lines skipped); ValueError in one
    sentence otherwise."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    from snreg.files import read_text_file

    text = read_text_file(path, "IMU orientation", ValueError, max_bytes=16 << 20)
    try:
        rows = list(csv.DictReader(line for line in text.splitlines() if not line.lstrip().startswith("#")))
    except csv.Error as err:
        raise ValueError(f"{path}: not a readable CSV ({err})") from None
    if not rows or not {"yaw", "pitch", "roll"} <= set(rows[0]):
        raise ValueError(f"{path}: the IMU file needs a header with the columns yaw,pitch,roll (degrees)")
    try:
        angles = np.array([[float(row["yaw"]), float(row["pitch"]), float(row["roll"])] for row in rows])
    except (TypeError, ValueError):
        raise ValueError(f"{path}: yaw, pitch and roll must be numbers (degrees) in every row") from None
    if not np.all(np.isfinite(angles)):
        raise ValueError(f"{path}: yaw, pitch and roll must be finite numbers (degrees) in every row")
    if len(angles) != count:
        raise ValueError(f"{path} has {len(angles)} IMU rows for {count} {per}s; give one row per {per}")
    return Rotation.from_euler("ZYX", angles, degrees=True)
