"""Stereo calibrations written by other tools, read into a :class:`StereoCalibration` (``snreg calibrate import``).

Why: a site that has calibrated its endoscope with OpenCV or NifTK/scikit-surgery should not have to
calibrate again for snreg. Three layouts are read:

- OpenCV's ``samples/cpp/stereo_calib.cpp``: ``intrinsics.yml`` with ``M1 D1 M2 D2`` and ``extrinsics.yml``
  with ``R T`` and optionally ``R1 R2 P1 P2 Q`` (FileStorage YAML or XML; no image size).
- snreg's own keys ``K1 D1 K2 D2 R T`` in one or more FileStorage files, with or without the rectification
  and the image size.
- NifTK / scikit-surgery folders (UCL's laparoscope datasets): ``calib.left.intrinsic(s).{txt,xml}``,
  ``calib.left.distortion.{txt,xml}``, the same for ``right``, and either ``calib.r2l.rotation.xml`` +
  ``calib.r2l.translation.xml`` or ``calib.l2r.txt`` (3 rows of R, then a row T) / ``calib.l2r.4x4``
  (homogeneous). Whatever the name says, r2l and l2r hold what OpenCV's ``stereoCalibrate`` returns:
  ``x_right = R x_left + T``. Text files hold whitespace-separated numbers (intrinsics 3 x 3, distortion
  1 x 5); XML files one OpenCV matrix each. A name may carry a prefix (``viking.calib.left...``).

T is kept in the units given (snreg expects mm). The rectification is computed when the files lack it.
"""

from __future__ import annotations

import datetime
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from snreg.camera.calibration import StereoCalibration, calibration_from_arrays
from snreg.errors import CalibrationFileError
from snreg.files import read_storage, read_text_file

__all__ = ["ImportedCalibration", "import_calibration", "LAYOUTS"]

LAYOUTS = ("OpenCV stereo_calib.cpp (intrinsics.yml M1 D1 M2 D2 + extrinsics.yml R T [R1 R2 P1 P2 Q])",
           "snreg keys K1 D1 K2 D2 R T without rectification",
           "a NifTK/scikit-surgery folder (calib.left.intrinsic(s), calib.left.distortion, the same for right, "
           "calib.r2l.rotation + calib.r2l.translation or calib.l2r.txt / calib.l2r.4x4)")
_NIFTK_ROLES = {"left intrinsics": r"calib\.left\.intrinsics?\.(txt|xml)", "left distortion": r"calib\.left\.distortion\.(txt|xml)",
                "right intrinsics": r"calib\.right\.intrinsics?\.(txt|xml)",
                "right distortion": r"calib\.right\.distortion\.(txt|xml)",
                "r2l rotation": r"calib\.r2l\.rotation\.(txt|xml)", "r2l translation": r"calib\.r2l\.translation\.(txt|xml)",
                "l2r": r"calib\.l2r\.(txt|4x4)"}
_NIFTK_NAME = re.compile(r"(^|\.)calib\.(left|right|r2l|l2r)\.")
_STORAGE_SUFFIXES = (".yml", ".yaml", ".xml", ".json", ".gz")
_MATRIX_KEYS = ("M1", "M2", "K1", "K2", "D1", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q")


@dataclass(frozen=True)
class ImportedCalibration:
    """The calibration read, which layout it came in, and whether its rectification was computed here."""

    calibration: StereoCalibration
    layout: str
    rectification_computed: bool


def import_calibration(sources: Sequence[str | Path], image_size: tuple[int, int] | None = None) -> ImportedCalibration:
    """Read another tool's stereo calibration from files and/or folders (module docstring for the layouts).

    ``image_size`` (width, height) is needed when the files do not carry it; when they do, it must agree.
    Raises :class:`CalibrationFileError` naming what was found and what was expected.
    """
    files = _files(sources)
    if any(_NIFTK_NAME.search(f.name) for f in files):
        layout, size, matrices = "NifTK/scikit-surgery folder", None, _niftk(files, _label(sources))
    else:
        layout, size, matrices = _file_storage([f for f in files if f.suffix.lower() in _STORAGE_SUFFIXES] or files,
                                               _label(sources))
    if size is not None and image_size is not None and tuple(size) != tuple(image_size):
        raise CalibrationFileError(f"{_label(sources)}: the files are for {size[0]:g}x{size[1]:g} images but "
                                   f"{image_size[0]}x{image_size[1]} was given; give the size the calibration was made at")
    size = size if size is not None else image_size
    if size is None:
        raise CalibrationFileError(f"{_label(sources)}: the {layout} files do not give the image size; "
                                   "give it (--image-size WxH, or --frame IMAGE to read it from a frame)")
    computed = "R1" not in matrices
    stamp = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    try:
        calibration = calibration_from_arrays(size, matrices, {"created_utc": stamp})
    except ValueError as err:
        raise CalibrationFileError(f"{_label(sources)}: {err}") from None
    return ImportedCalibration(calibration, layout, computed)


def _label(sources: Sequence[str | Path]) -> str:
    return ", ".join(str(s) for s in sources)


def _files(sources: Sequence[str | Path]) -> list[Path]:
    """The files given and those directly inside the folders given, sorted; missing paths are an error."""
    if not sources:
        raise CalibrationFileError("no calibration files or folder given")
    files = []
    for source in map(Path, sources):
        if source.is_dir():
            files += sorted(p for p in source.iterdir() if p.is_file())
        elif source.is_file():
            files.append(source)
        else:
            raise CalibrationFileError(f"{source}: no such file or folder")
    if not files:
        raise CalibrationFileError(f"{_label(sources)}: no files in the folder(s) given")
    return files


def _file_storage(files: list[Path], label: str) -> tuple[str, tuple[int, int] | None, dict[str, np.ndarray]]:
    """OpenCV stereo_calib or snreg-style keys merged from FileStorage files; (layout, size or None, matrices)."""
    values: dict[str, np.ndarray] = {}
    numbers: dict[str, float] = {}
    origin: dict[str, str] = {}
    broken: dict[str, str] = {}
    for path in files:
        stored = read_storage(path, "calibration", CalibrationFileError)
        for key in stored.keys:
            if key in origin:
                raise CalibrationFileError(f"{label}: {key} appears in both {origin[key]} and {path.name}; "
                                           "give each key once")
            origin[key] = path.name
        values.update(stored.matrices)
        numbers.update(stored.numbers)
        broken.update({key: why for key, why in stored.broken.items() if key in _MATRIX_KEYS})
    opencv = "M1" in values or "M2" in values
    if opencv and ("K1" in values or "K2" in values):
        raise CalibrationFileError(f"{label}: holds both M1/M2 (OpenCV) and K1/K2 (snreg) camera matrices; give one set")
    names = {"K1": "M1", "K2": "M2"} if opencv else {}
    expected = [names.get(k, k) for k in ("K1", "D1", "K2", "D2", "R", "T")]
    wrong = [k for k in expected if k in broken or (k in origin and k not in values)]
    if wrong:
        raise CalibrationFileError(f"{label}: {wrong[0]} in {origin[wrong[0]]} is "
                                   f"{broken.get(wrong[0]) or 'a single number or text'}; it must be an opencv-matrix")
    missing = [k for k in expected if k not in values]
    if missing:
        found = "; ".join(f"{name}: {', '.join(k for k, o in origin.items() if o == name)}"
                          for name in dict.fromkeys(origin.values())) or "no keys"
        raise CalibrationFileError(f"{label}: cannot import: lacks {', '.join(missing)} (found {found}); expected one of: "
                                   + "; ".join(LAYOUTS))
    matrices = {k: values[names.get(k, k)] for k in ("K1", "D1", "K2", "D2", "R", "T")}
    rectification = [k for k in ("R1", "R2", "P1", "P2", "Q") if k in values]
    if len(rectification) == 5:
        matrices.update({k: values[k] for k in rectification})
    size = None
    if "image_width" in numbers and "image_height" in numbers:
        size = (numbers["image_width"], numbers["image_height"])
    return ("OpenCV stereo_calib" if opencv else "snreg keys"), size, matrices


def _niftk(files: list[Path], label: str) -> dict[str, np.ndarray]:
    """K1 D1 K2 D2 R T from the files of a NifTK/scikit-surgery calibration folder."""
    found = {}
    for role, pattern in _NIFTK_ROLES.items():
        matches = [f for f in files if re.search(rf"(^|\.){pattern}$", f.name)]
        if len(matches) > 1:
            raise CalibrationFileError(f"{label}: several files for the {role}: {', '.join(m.name for m in matches)}; "
                                       "keep one")
        if matches:
            found[role] = matches[0]
    extrinsics = ({"r2l rotation", "r2l translation"} <= set(found)) or "l2r" in found
    missing = [r for r in ("left intrinsics", "left distortion", "right intrinsics", "right distortion") if r not in found]
    if missing or not extrinsics:
        have = ", ".join(f.name for f in files if _NIFTK_NAME.search(f.name))
        lacking = missing + ([] if extrinsics else ["calib.r2l.rotation + calib.r2l.translation, or calib.l2r"])
        raise CalibrationFileError(f"{label}: the NifTK/scikit-surgery calibration lacks {', '.join(lacking)} (found {have}); "
                                   "expected calib.left.intrinsic(s).{txt,xml}, calib.left.distortion.{txt,xml}, the same "
                                   "for right, and calib.r2l.rotation.xml + calib.r2l.translation.xml or "
                                   "calib.l2r.txt / calib.l2r.4x4")
    matrices = {"K1": _matrix(found["left intrinsics"]), "D1": _matrix(found["left distortion"]),
                "K2": _matrix(found["right intrinsics"]), "D2": _matrix(found["right distortion"])}
    if "r2l rotation" in found and "r2l translation" in found:
        matrices["R"], matrices["T"] = _matrix(found["r2l rotation"]), _matrix(found["r2l translation"])
    else:
        matrices["R"], matrices["T"] = _rigid(_matrix(found["l2r"]), found["l2r"])
    return matrices


def _rigid(matrix: np.ndarray, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(R, T) from a 4x3 (R rows, then T), 3x4 ([R | T]) or 4x4 homogeneous matrix."""
    if matrix.shape == (4, 3):
        return matrix[:3], matrix[3]
    if matrix.shape == (3, 4):
        return matrix[:, :3], matrix[:, 3]
    if matrix.shape == (4, 4):
        if not np.allclose(matrix[3], [0, 0, 0, 1], atol=1e-9):
            raise CalibrationFileError(f"{path}: a 4x4 rigid transform must end in the row 0 0 0 1, got "
                                       f"{' '.join(f'{v:g}' for v in matrix[3])}")
        return matrix[:3, :3], matrix[:3, 3]
    raise CalibrationFileError(f"{path}: expected R and T as 4x3 (three rows of R, then T), 3x4 or 4x4 numbers, "
                               f"got {matrix.shape[0]}x{matrix.shape[1]}")


def _matrix(path: Path) -> np.ndarray:
    """The numbers of a text file (rows of whitespace- or comma-separated numbers) or the one matrix of an XML/YAML file."""
    if path.suffix.lower() in _STORAGE_SUFFIXES:
        stored = read_storage(path, "calibration matrix", CalibrationFileError)
        first = stored.keys[0] if stored.keys else None
        if first not in stored.matrices:
            raise CalibrationFileError(f"{path}: holds no OpenCV matrix (expected one <type_id=\"opencv-matrix\"> node"
                                       + (f"; {first} is {stored.kind(first)})" if first else ")"))
        return stored.matrices[first]
    text = read_text_file(path, "calibration matrix", CalibrationFileError, max_bytes=1 << 20).replace(",", " ")
    try:
        rows = [[float(v) for v in line.split()] for line in text.splitlines() if line.strip()]
    except ValueError:
        raise CalibrationFileError(f"{path}: holds something that is not a number; expected rows of numbers") from None
    if not rows or len({len(r) for r in rows}) != 1:
        raise CalibrationFileError(f"{path}: expected rows of equal length of numbers, got rows of "
                                   f"{', '.join(str(len(r)) for r in rows) or 'nothing'}")
    return np.array(rows, dtype=float)
