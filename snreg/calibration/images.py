"""Calibration images from files: glob patterns in natural order, read as 8-bit grey with one clear error."""

from __future__ import annotations

import glob
import re
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from snreg.files import read_image

__all__ = ["expand_globs", "read_grey"]


def _natural_key(path: str) -> list:
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path)]


def expand_globs(patterns: str | Sequence[str], side: str) -> list[str]:
    """Files matching one or more glob patterns, in natural order; ValueError naming ``side`` if none."""
    patterns = [patterns] if isinstance(patterns, str) else list(patterns)
    paths = {p for pattern in patterns for p in glob.glob(str(Path(pattern).expanduser())) if Path(p).is_file()}
    if not paths:
        raise ValueError(f"no files match the {side} pattern {' '.join(patterns)!r}")
    return sorted(paths, key=_natural_key)


def read_grey(path: str) -> np.ndarray:
    """An image file as 8-bit grey; ValueError when it is not a readable image."""
    return read_image(path, cv2.IMREAD_GRAYSCALE)
