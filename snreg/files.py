"""Opening OpenCV ``FileStorage`` files (calibration, probe model) with one clear error."""

from __future__ import annotations

from pathlib import Path

import cv2

__all__ = ["open_for_reading"]


def open_for_reading(path: str | Path, what: str, error: type[Exception] = ValueError) -> cv2.FileStorage:
    """Open ``path`` for reading; raise ``error`` naming ``what`` when it is missing or not such a file."""
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
