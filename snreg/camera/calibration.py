"""The stereo calibration and its OpenCV ``FileStorage`` YAML file (docs/design.md, Calibration file).

Keys: ``image_width``, ``image_height``, ``K1 D1 K2 D2 R T`` (OpenCV ``stereoCalibrate``:
``R, T`` map left-camera coordinates into the right camera, T in mm), the rectification
``R1 R2 P1 P2 Q`` (``stereoRectify`` with zero disparity at infinity), ``rms_reprojection_px``,
``board_cols``, ``board_rows`` (inner corners), ``square_mm``, ``n_views``, ``created_utc``,
``snreg_version``.
"""

from __future__ import annotations

import datetime
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from snreg import __version__
from snreg.errors import CalibrationFileError
from snreg.camera.plausibility import check_bounds, check_rectification
from snreg.files import atomic_write, read_storage

__all__ = ["StereoCalibration", "CalibrationFileError", "load_calibration", "save_calibration", "thesis_calibration",
           "calibration_from_arrays", "missing_keys_message", "REQUIRED_KEYS", "THESIS_CALIBRATION_PATH"]

THESIS_CALIBRATION_PATH = Path(__file__).resolve().parents[2] / "resources" / "calibration" / "thesis_appendix_a.yaml"
_MATRICES = ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q")
_RECTIFICATION = ("R1", "R2", "P1", "P2", "Q")
REQUIRED_KEYS = ("image_width", "image_height", "K1", "D1", "K2", "D2", "R", "T")
_SHAPES = {"K1": (3, 3), "D1": None, "K2": (3, 3), "D2": None, "R": (3, 3), "T": (3, 1),
           "R1": (3, 3), "R2": (3, 3), "P1": (3, 4), "P2": (3, 4), "Q": (4, 4)}
_DISTORTION_SIZES = (4, 5, 8, 12, 14)


@dataclass(frozen=True)
class StereoCalibration:
    """A calibrated stereo pair; mm and pixels. ``image_size`` is (width, height)."""

    image_size: tuple[int, int]
    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    rms_reprojection_px: float = float("nan")
    board_cols: int = 0
    board_rows: int = 0
    square_mm: float = 0.0
    n_views: int = 0
    created_utc: str = field(default_factory=lambda: datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"))
    snreg_version: str = __version__

    @classmethod
    def from_pair(cls, image_size, K1, D1, K2, D2, R, T, **meta) -> "StereoCalibration":
        """Complete a calibration with its rectification (``cv2.stereoRectify``, zero disparity, alpha 0)."""
        K1, K2, R = (np.asarray(a, dtype=float).reshape(3, 3) for a in (K1, K2, R))
        D1, D2 = (np.asarray(d, dtype=float).reshape(1, -1) for d in (D1, D2))
        T = np.asarray(T, dtype=float).reshape(3, 1)
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(K1, D1, K2, D2, tuple(int(v) for v in image_size), R, T,
                                                    flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
        return cls((int(image_size[0]), int(image_size[1])), K1, D1, K2, D2, R, T, R1, R2, P1, P2, Q, **meta)

    @property
    def baseline_mm(self) -> float:
        return float(np.linalg.norm(self.T))

    def scaled(self, factor: float) -> "StereoCalibration":
        """The same cameras at ``factor`` times the resolution (intrinsics scaled, rectification redone)."""
        scale = np.diag([factor, factor, 1.0])
        size = (round(self.image_size[0] * factor), round(self.image_size[1] * factor))
        meta = {k: getattr(self, k) for k in ("rms_reprojection_px", "board_cols", "board_rows", "square_mm", "n_views")}
        return StereoCalibration.from_pair(size, scale @ self.K1, self.D1, scale @ self.K2, self.D2, self.R, self.T, **meta)


def save_calibration(calib: StereoCalibration, path: str | Path) -> None:
    """Write ``calib`` as the calibration file (docs/design.md, Contracts), atomically; ``OSError`` when it cannot be written."""
    fs = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)
    fs.write("image_width", int(calib.image_size[0]))
    fs.write("image_height", int(calib.image_size[1]))
    for name in _MATRICES:
        fs.write(name, np.asarray(getattr(calib, name), dtype=float))
    fs.write("rms_reprojection_px", float(calib.rms_reprojection_px))
    fs.write("board_cols", int(calib.board_cols))
    fs.write("board_rows", int(calib.board_rows))
    fs.write("square_mm", float(calib.square_mm))
    fs.write("n_views", int(calib.n_views))
    fs.write("created_utc", calib.created_utc)
    fs.write("snreg_version", calib.snreg_version)
    text = fs.releaseAndGetString()
    with atomic_write(path) as temporary:
        temporary.write_text(text, encoding="utf-8")


def load_calibration(path: str | Path) -> StereoCalibration:
    """Read a snreg calibration file; :class:`CalibrationFileError` names the keys found and those expected, or the
    value that is wrong.

    The rectification ``R1 R2 P1 P2 Q`` may be absent: it is then computed (``cv2.stereoRectify``, as
    :meth:`StereoCalibration.from_pair`) from the rest and the image size.
    """
    path = Path(path)
    stored = read_storage(path, "calibration", CalibrationFileError)
    matrices = {name: stored.matrices[name] for name in _MATRICES if name in stored.matrices}
    numbers = {key: stored.numbers[key] for key in ("image_width", "image_height", "rms_reprojection_px", "board_cols",
                                                    "board_rows", "square_mm", "n_views") if key in stored.numbers}
    texts = {key: stored.texts[key] for key in ("created_utc", "snreg_version") if key in stored.texts}
    wrong = [k for k in REQUIRED_KEYS + _RECTIFICATION if k in stored.keys and k not in matrices and k not in numbers]
    if wrong:
        expected = "a whole number of pixels" if wrong[0].startswith("image_") else "an opencv-matrix"
        raise CalibrationFileError(f"{path}: {wrong[0]} is {stored.kind(wrong[0])}; it must be {expected}")
    missing = [k for k in REQUIRED_KEYS if k not in matrices and k not in numbers]
    if missing:
        raise CalibrationFileError(f"{path}: {missing_keys_message(stored.keys, missing)}")
    meta = {"rms_reprojection_px": numbers.get("rms_reprojection_px", float("nan")),
            "board_cols": _count(numbers.get("board_cols", 0)), "board_rows": _count(numbers.get("board_rows", 0)),
            "square_mm": numbers.get("square_mm", 0.0), "n_views": _count(numbers.get("n_views", 0)), **texts}
    size = (numbers["image_width"], numbers["image_height"])
    rectification = [k for k in _RECTIFICATION if k in matrices]
    if rectification and len(rectification) < len(_RECTIFICATION):
        lacking = ", ".join(k for k in _RECTIFICATION if k not in matrices)
        raise CalibrationFileError(f"{path}: the rectification is incomplete (lacks {lacking}); give all of "
                                   f"{' '.join(_RECTIFICATION)} or none, and snreg computes them")
    try:
        return calibration_from_arrays(size, matrices, meta)
    except ValueError as err:
        raise CalibrationFileError(f"{path}: {err}") from None


def _count(value: float) -> int:
    """A count from the file's metadata (views, board corners); 0 when it is not a sensible whole number."""
    return int(value) if np.isfinite(value) and 0 <= value < 1e9 else 0


def missing_keys_message(found: tuple[str, ...], missing: list[str]) -> str:
    """One sentence: which keys a snreg calibration file lacks, which it has, and what to do with another tool's file."""
    has = ", ".join(found) if found else "no keys"
    hint = "convert another tool's calibration with 'snreg calibrate import SRC... --image-size WxH -o calib.yaml'"
    if {"M1", "M2"} & set(found) or {"calib_left_intrinsic", "calib_r2l_rotation"} & set(found):
        hint = "this looks like another tool's calibration: " + hint
    return (f"not a snreg calibration: it lacks {', '.join(missing)} (it has {has}; a snreg calibration needs "
            f"{', '.join(REQUIRED_KEYS)}, with {' '.join(_RECTIFICATION)} optional); {hint}")


def calibration_from_arrays(image_size, matrices: dict[str, np.ndarray], meta: dict | None = None) -> StereoCalibration:
    """A checked :class:`StereoCalibration` from ``K1 D1 K2 D2 R T`` (and optionally ``R1 R2 P1 P2 Q``).

    Rectification is computed when absent; given, it must follow from ``R`` and ``T``
    (:func:`~snreg.camera.plausibility.check_rectification`). Raises ``ValueError`` saying which value is wrong:
    non-positive image size, wrong shape, NaN or infinite entries, a focal length that is not positive, an ``R`` that
    is not a rotation, a zero ``T``, a value beyond any plausible camera (:func:`~snreg.camera.plausibility.check_bounds`).
    """
    meta = dict(meta or {})
    width, height = (float(v) for v in image_size)
    if not (np.isfinite(width) and np.isfinite(height) and width >= 1 and height >= 1 and width == int(width)
            and height == int(height)):
        raise ValueError(f"the image size must be two positive whole numbers of pixels, got {image_size[0]:g}x{image_size[1]:g}")
    size = (int(width), int(height))
    values = {}
    for name, shape in _SHAPES.items():
        if name not in matrices:
            continue
        value = np.asarray(matrices[name], dtype=float)
        if name in ("D1", "D2"):
            if value.size not in _DISTORTION_SIZES:
                raise ValueError(f"{name} has {value.size} values; OpenCV distortion has 4, 5, 8, 12 or 14")
            value = value.reshape(1, -1)
        elif name == "T":
            if value.size != 3:
                raise ValueError(f"T must have 3 values (mm), got shape {value.shape}")
            value = value.reshape(3, 1)
        elif value.shape != shape:
            raise ValueError(f"{name} has shape {value.shape}, expected {shape}")
        if not np.all(np.isfinite(value)):
            raise ValueError(f"{name} holds NaN or infinite values")
        values[name] = value
    for name in ("K1", "K2"):
        K = values[name]
        if not (K[0, 0] > 0 and K[1, 1] > 0) or not np.allclose(K[2], [0, 0, 1]):
            raise ValueError(f"{name} is not a camera matrix: its focal lengths must be positive (got "
                             f"{K[0, 0]:g}, {K[1, 1]:g}) and its last row 0 0 1")
    R = values["R"]
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        raise ValueError("R is not a rotation matrix (R R^T must be the identity and det R = +1)")
    with np.errstate(over="ignore"):
        baseline = float(np.linalg.norm(values["T"]))
    if not baseline > 1e-6:
        raise ValueError("T is zero: the two cameras cannot be in one place")
    check_bounds(size, values)
    if "R1" not in values:
        return StereoCalibration.from_pair(size, *(values[k] for k in ("K1", "D1", "K2", "D2", "R", "T")), **meta)
    try:
        check_rectification(values)
    except ValueError as err:
        raise ValueError(f"the given rectification does not follow from K1 D1 K2 D2 R T: {err}; leave R1 R2 P1 P2 Q "
                         "out and snreg computes them") from None
    return StereoCalibration(size, **values, **meta)


def thesis_calibration() -> StereoCalibration:
    """The Firefly calibration of thesis Appendix A (1920x1080, zero distortion), shipped in ``resources/``."""
    return load_calibration(THESIS_CALIBRATION_PATH)


def _thesis_values() -> StereoCalibration:
    """Appendix A, typed in: both cameras share K; R and T as printed (T in mm)."""
    K = np.array([[1.0706188663934486e03, 0.0, 9.3580034306269090e02],
                  [0.0, 1.0715737551305006e03, 5.0638640756917050e02],
                  [0.0, 0.0, 1.0]])
    R = np.array([[9.9999889817438115e-01, 6.9786956762589577e-05, -1.4828283124567402e-03],
                  [-6.7762527451174065e-05, 9.9999906574306940e-01, 1.3652550048496655e-03],
                  [1.4829222041061075e-03, -1.3651530203824948e-03, 9.9999796864742052e-01]])
    T = np.array([-4.3014683359121166e00, 0.0, 0.0])
    return replace(StereoCalibration.from_pair((1920, 1080), K, np.zeros(5), K, np.zeros(5), R, T),
                   created_utc="thesis Appendix A", board_cols=10, board_rows=7, square_mm=10.0, n_views=30)
