"""The stereo calibration and its OpenCV ``FileStorage`` YAML file (DESIGN.md §4, Calibration file).

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
from snreg.files import open_for_reading

__all__ = ["StereoCalibration", "CalibrationFileError", "load_calibration", "save_calibration", "thesis_calibration",
           "THESIS_CALIBRATION_PATH"]

THESIS_CALIBRATION_PATH = Path(__file__).resolve().parents[1] / "resources" / "calibration" / "thesis_appendix_a.yaml"
_MATRICES = ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q")


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
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
    try:
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
    finally:
        fs.release()


def load_calibration(path: str | Path) -> StereoCalibration:
    """Read a calibration file; :class:`CalibrationFileError` says what is missing or wrong."""
    path = Path(path)
    fs = open_for_reading(path, "calibration", CalibrationFileError)
    try:
        values = {}
        for name in _MATRICES:
            node = fs.getNode(name)
            if node.empty() or not node.isMap():
                raise CalibrationFileError(f"{path}: calibration lacks the matrix {name}; recalibrate or use the thesis file")
            values[name] = np.asarray(node.mat(), dtype=float)
        width, height = fs.getNode("image_width").real(), fs.getNode("image_height").real()
        if not (width > 0 and height > 0):
            raise CalibrationFileError(f"{path}: calibration lacks image_width/image_height")

        def text(key: str) -> str:
            node = fs.getNode(key)
            return node.string() if not node.empty() else ""

        meta = {"rms_reprojection_px": fs.getNode("rms_reprojection_px").real() if not fs.getNode("rms_reprojection_px").empty() else float("nan"),
                "board_cols": int(fs.getNode("board_cols").real()), "board_rows": int(fs.getNode("board_rows").real()),
                "square_mm": fs.getNode("square_mm").real(), "n_views": int(fs.getNode("n_views").real()),
                "created_utc": text("created_utc"), "snreg_version": text("snreg_version")}
    finally:
        fs.release()
    shapes = {"K1": (3, 3), "K2": (3, 3), "R": (3, 3), "R1": (3, 3), "R2": (3, 3), "P1": (3, 4), "P2": (3, 4), "Q": (4, 4)}
    for name, shape in shapes.items():
        if values[name].shape != shape:
            raise CalibrationFileError(f"{path}: {name} has shape {values[name].shape}, expected {shape}")
    if values["T"].size != 3:
        raise CalibrationFileError(f"{path}: T must have 3 values (mm)")
    values["T"] = values["T"].reshape(3, 1)
    values["D1"], values["D2"] = values["D1"].reshape(1, -1), values["D2"].reshape(1, -1)
    return StereoCalibration((int(width), int(height)), **values, **meta)


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
