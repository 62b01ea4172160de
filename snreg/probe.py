"""The DROP-IN probe model: geometry and colours, read from a file (docs/design.md, Probe model).

Default (``resources/probe/drop_in_probe.yaml``): a cylinder 10 mm in diameter, tip on its
axis at 0; three green stripes 4 mm wide centred 20, 30 and 40 mm from the tip; a dark
grey body; tracked 20-300 mm from the camera (the thesis measured up to 290 mm). The file is
OpenCV ``FileStorage`` YAML like the calibration file; ``working_range_mm`` may be left out.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from snreg.files import atomic_write, read_storage

__all__ = ["ProbeModel", "load_probe_model", "save_probe_model", "default_probe_model", "DEFAULT_PROBE_PATH"]

DEFAULT_PROBE_PATH = Path(__file__).resolve().parents[1] / "resources" / "probe" / "drop_in_probe.yaml"


@dataclass(frozen=True)
class ProbeModel:
    """Probe geometry (mm, along the axis from the tip) and colours (BGR, HSV ranges in OpenCV units)."""

    diameter_mm: float
    length_mm: float
    stripe_centres_mm: tuple[float, ...]
    stripe_width_mm: float
    stripe_bgr: tuple[int, int, int]
    body_bgr: tuple[int, int, int]
    hsv_low: tuple[int, int, int]
    hsv_high: tuple[int, int, int]
    working_range_mm: tuple[float, float] = (20.0, 300.0)   # tip-to-camera depths it is tracked at (``--depth-range``)

    @property
    def radius_mm(self) -> float:
        return self.diameter_mm / 2.0

    @property
    def band_centre_mm(self) -> float:
        """Distance from the tip to the middle of the stripe band."""
        return float(np.mean(self.stripe_centres_mm))

    def stripe_at(self, s_mm: np.ndarray) -> np.ndarray:
        """Index of the stripe covering axial position(s) ``s_mm``, -1 where none."""
        s = np.asarray(s_mm, dtype=float)
        index = np.full(s.shape, -1, dtype=int)
        for k, centre in enumerate(self.stripe_centres_mm):
            index[np.abs(s - centre) <= self.stripe_width_mm / 2.0] = k
        return index


def save_probe_model(model: ProbeModel, path: str | Path) -> None:
    """Write ``model`` as a probe model file, atomically; ``OSError`` when it cannot be written."""
    fs = cv2.FileStorage(".yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY | cv2.FILE_STORAGE_FORMAT_YAML)
    fs.write("diameter_mm", float(model.diameter_mm))
    fs.write("length_mm", float(model.length_mm))
    fs.write("stripe_width_mm", float(model.stripe_width_mm))
    for key in ("stripe_centres_mm", "stripe_bgr", "body_bgr", "hsv_low", "hsv_high", "working_range_mm"):
        fs.write(key, np.asarray(getattr(model, key), dtype=float).reshape(1, -1))
    text = fs.releaseAndGetString()
    with atomic_write(path) as temporary:
        temporary.write_text(text, encoding="utf-8")


def load_probe_model(path: str | Path | None = None) -> ProbeModel:
    """Read a probe model file (the default when ``path`` is None); ValueError says what is wrong."""
    path = Path(path) if path is not None else DEFAULT_PROBE_PATH
    stored = read_storage(path, "probe model", ValueError)

    def number(key):
        if key not in stored.numbers:
            raise ValueError(f"{path}: probe model lacks {key}" if key not in stored.keys else
                             f"{path}: {key} is {stored.kind(key)}; it must be a number")
        return stored.numbers[key]

    def row(key, n=None):
        if key not in stored.matrices:
            raise ValueError(f"{path}: probe model lacks {key}" if key not in stored.keys else
                             f"{path}: {key} is {stored.kind(key)}; it must be an opencv-matrix")
        values = stored.matrices[key].ravel()
        if n is not None and len(values) != n:
            raise ValueError(f"{path}: {key} needs {n} values")
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{path}: {key} holds NaN or infinite values")
        return values

    model = ProbeModel(number("diameter_mm"), number("length_mm"), tuple(float(v) for v in row("stripe_centres_mm")),
                       number("stripe_width_mm"),
                       *(tuple(int(v) for v in row(k, 3)) for k in ("stripe_bgr", "body_bgr", "hsv_low", "hsv_high")),
                       **({} if "working_range_mm" not in stored.keys else
                          {"working_range_mm": tuple(float(v) for v in row("working_range_mm", 2))}))
    if model.diameter_mm <= 0 or len(model.stripe_centres_mm) < 2:
        raise ValueError(f"{path}: a probe needs a positive diameter and at least two stripes")
    near, far = model.working_range_mm
    if not 0 < near < far:
        raise ValueError(f"{path}: working_range_mm must be two depths 0 < near < far (mm), got {near:g}, {far:g}")
    return model


def default_probe_model() -> ProbeModel:
    return load_probe_model(DEFAULT_PROBE_PATH)
