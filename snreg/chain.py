"""The transform chain from the camera to the trocar frame (thesis §3.5, Fig 7-8): the one place that composes it.

A stored node at ``p_camera`` (mm, left camera frame) lies in the trocar frame at::

    p_trocar = trocar_from_imu(t) @ imu_from_camera @ p_camera

- ``imu_from_camera`` (4, 4) is fixed by the mount: the IMU-camera rotation (the thesis aligned the
  axes by eye, the identity; :func:`snreg.calibration.pivot.imu_camera_rotation` measures it) and the
  camera origin on the shaft ``imu_trocar_mm + trocar_camera_mm`` ahead of the IMU (thesis §4.1:
  460 + 158 mm).
- ``trocar_from_imu(t)`` (thesis Fig 8B): the IMU sits on the shaft ``imu_trocar_mm`` behind the pivot;
  its orientation at time t (``earth_from_imu``, sensor to earth, as an AHRS gives it) turned into the
  trocar frame by the reference orientation ``trocar_from_earth`` rotates that lever about the pivot.

Frames: the trocar frame has its origin at the pivot and, in the reference pose
(:meth:`ChainCalibration.with_reference`), z along the shaft *into* the patient and x, y the camera's
turned by the least rotation that does so (none for a camera looking along the shaft): the camera at
``z = +trocar_camera_mm``, the IMU at ``z = -imu_trocar_mm`` (the thesis's Fig 8B counts d upwards).

Gravity: the IMU's earth frame (imufusion's NWU, :mod:`snreg.imu.fusion`) has z up, so gravity points along
``EARTH_DOWN`` in it and along :attr:`ChainCalibration.down_trocar` in the trocar frame. A 6-axis IMU's heading drifts
about that very axis, so the drift never moves the down; the down is one vector for every node a chain maps.

The IMU-trocar distance cancels in the product: the camera sits at ``-R_camera(t) p_camera`` from the
pivot whatever the IMU's lever, so only the trocar-camera distance and the rotations matter, and the
7 cm spread of the thesis's arc method (§4.1, Table 2) cannot reach the nodes as long as one value
enters both transforms, as here.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.files import read_text_file
from snreg.geometry import apply, make_transform

__all__ = ["THESIS_IMU_TROCAR_MM", "THESIS_TROCAR_CAMERA_MM", "THESIS_TROCAR_CAMERA_SD_MM", "EARTH_DOWN", "ChainCalibration", "reference_rotation",
           "trocar_from_imu", "trocar_from_camera", "camera_from_probe", "trocar_from_probe", "camera_to_trocar",
           "read_chain_file"]

# thesis §4.1: the IMU-trocar distance measured by hand, and the trocar-camera distance it measured (mm)
THESIS_IMU_TROCAR_MM = 460.0
THESIS_TROCAR_CAMERA_MM = 158.0
# the trocar-camera distance's own error (thesis Table 3: interquartile 157-158 mm over orientations, so a robust sd of
# 1 / 1.349 mm): the sd of the insertion the trocar calibration gives, where insertion tracking starts
THESIS_TROCAR_CAMERA_SD_MM = 0.74
EARTH_DOWN = np.array([0.0, 0.0, -1.0])     # gravity in the IMU's earth frame (z up: at rest the accelerometer reads +1 g)

_TRANSFORMS = ("imu_from_camera", "trocar_from_earth")
_ORTHONORMAL_TOL = 1e-6
_LAST_ROW, _EYE3 = np.array([0.0, 0.0, 0.0, 1.0]), np.eye(3)


@dataclass(frozen=True, eq=False)
class ChainCalibration:
    """The calibrated constants of the chain; mm.

    ``imu_from_camera`` (4, 4): camera to IMU, the camera origin on the shaft ahead of the IMU.
    ``imu_trocar_mm``: distance from the IMU to the pivot along the shaft (the line from the IMU to the
    camera origin), less than their distance. ``trocar_from_earth`` (4, 4, rotation only): the
    reference orientation; the identity until :meth:`with_reference` sets it (the thesis used the IMU
    angles as they came, i.e. the identity).
    """

    imu_from_camera: np.ndarray
    imu_trocar_mm: float
    trocar_from_earth: np.ndarray = field(default_factory=lambda: np.eye(4))

    def __post_init__(self):
        for name in _TRANSFORMS:
            object.__setattr__(self, name, _rigid(getattr(self, name), name))
        if np.any(self.trocar_from_earth[:3, 3] != 0):
            raise ValueError("trocar_from_earth is a reference orientation and must have zero translation")
        imu_camera_mm = float(np.linalg.norm(self.imu_from_camera[:3, 3]))
        if not 0.0 <= self.imu_trocar_mm < imu_camera_mm:
            raise ValueError(f"the IMU-trocar distance ({self.imu_trocar_mm} mm) must lie between 0 and the IMU-camera "
                             f"distance ({imu_camera_mm:.1f} mm): the pivot is on the shaft between them")
        object.__setattr__(self, "imu_trocar_mm", float(self.imu_trocar_mm))

    @classmethod
    def manual(cls, imu_trocar_mm: float = THESIS_IMU_TROCAR_MM,
               trocar_camera_mm: float = THESIS_TROCAR_CAMERA_MM) -> "ChainCalibration":
        """The thesis's chain (§4.1): axes aligned by eye (identity), the camera on the IMU's z axis.

        Defaults are the thesis's manual IMU-trocar measurement and its measured trocar-camera distance.
        """
        if not (trocar_camera_mm > 0 and imu_trocar_mm >= 0):
            raise ValueError(f"distances must be positive (mm), got IMU-trocar {imu_trocar_mm}, "
                             f"trocar-camera {trocar_camera_mm}")
        return cls(make_transform(np.eye(3), [0.0, 0.0, imu_trocar_mm + trocar_camera_mm]), imu_trocar_mm)

    @property
    def trocar_camera_mm(self) -> float:
        """Distance from the pivot to the camera origin, mm."""
        return float(np.linalg.norm(self.imu_from_camera[:3, 3])) - self.imu_trocar_mm

    @property
    def pivot_imu_mm(self) -> np.ndarray:
        """(3,) the pivot in the IMU frame, mm: ``imu_trocar_mm`` along the shaft towards the camera."""
        shaft = self.imu_from_camera[:3, 3]
        return self.imu_trocar_mm * shaft / np.linalg.norm(shaft)

    @property
    def shaft_camera(self) -> np.ndarray:
        """(3,) unit direction of the shaft into the patient (IMU to camera) in the camera frame."""
        shaft = self.imu_from_camera[:3, 3]
        return self.imu_from_camera[:3, :3].T @ shaft / np.linalg.norm(shaft)

    @property
    def down_trocar(self) -> np.ndarray:
        """(3,) unit: gravity's direction in the trocar frame, ``trocar_from_earth @ EARTH_DOWN`` (the intraop down a
        registration from gravity starts from; identity reference: (0, 0, -1))."""
        return self.trocar_from_earth[:3, :3] @ EARTH_DOWN

    def with_insertion(self, trocar_camera_mm: float) -> "ChainCalibration":
        """The same chain with the camera ``trocar_camera_mm`` from the pivot along its shaft (the camera slid
        through the trocar: what :mod:`snreg.odometry` measures); ValueError for a distance that is not positive."""
        distance = float(trocar_camera_mm)
        if not (np.isfinite(distance) and distance > 0):
            raise ValueError(f"the trocar-camera distance must be a positive number of mm, got {trocar_camera_mm}")
        transform = self.imu_from_camera.copy()
        shaft = transform[:3, 3] / np.linalg.norm(transform[:3, 3])
        transform[:3, 3] = (self.imu_trocar_mm + distance) * shaft
        return replace(self, imu_from_camera=transform)

    def with_reference(self, earth_from_imu) -> "ChainCalibration":
        """The same chain with the trocar axes fixed by the reference pose at this IMU orientation (3, 3) or Rotation."""
        camera_from_earth = (_orientation(earth_from_imu) @ self.imu_from_camera[:3, :3]).T
        return replace(self, trocar_from_earth=make_transform(reference_rotation(self.shaft_camera) @ camera_from_earth,
                                                              np.zeros(3)))

    def to_dict(self) -> dict:
        """JSON-ready: each transform as a nested list under its own name, distances in mm."""
        return {"imu_from_camera": self.imu_from_camera.tolist(), "trocar_from_earth": self.trocar_from_earth.tolist(),
                "imu_trocar_mm": self.imu_trocar_mm, "trocar_camera_mm": self.trocar_camera_mm}

    @classmethod
    def from_dict(cls, data: dict) -> "ChainCalibration":
        """Inverse of :meth:`to_dict`; ``trocar_camera_mm``, when present, must agree with the transform."""
        missing = [key for key in (*_TRANSFORMS, "imu_trocar_mm") if key not in data]
        if missing:
            raise ValueError(f"chain calibration lacks {', '.join(missing)}")
        try:
            chain = cls(np.asarray(data["imu_from_camera"], dtype=float), float(data["imu_trocar_mm"]),
                        np.asarray(data["trocar_from_earth"], dtype=float))
        except (TypeError, ValueError) as err:
            raise ValueError(f"chain calibration: {err}") from None
        if "trocar_camera_mm" in data and abs(float(data["trocar_camera_mm"]) - chain.trocar_camera_mm) > 1e-6:
            raise ValueError(f"chain calibration: trocar_camera_mm {data['trocar_camera_mm']} disagrees with "
                             f"imu_from_camera and imu_trocar_mm ({chain.trocar_camera_mm:.6f} mm)")
        return chain


def read_chain_file(path) -> ChainCalibration:
    """The chain in a file as ``snreg calibrate trocar`` writes it (JSON of :meth:`ChainCalibration.to_dict`);
    ValueError in one sentence naming the file when it is not one."""
    text = read_text_file(path, "chain", ValueError, max_bytes=1 << 20)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: not a chain file (JSON: {err.msg} at line {err.lineno})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a chain file (expected a JSON object as 'snreg calibrate trocar' writes)")
    try:
        return ChainCalibration.from_dict(data)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{path}: {err}") from None


def reference_rotation(shaft_camera: np.ndarray) -> np.ndarray:
    """(3, 3) ``trocar_from_camera`` rotation in the reference pose: the least rotation turning the shaft (3,) onto z.

    ``shaft_camera``: the shaft's direction into the patient in the camera frame (``-p_camera`` of the
    pivot calibration); for a camera looking along the shaft, the identity.
    """
    rotation, _ = Rotation.align_vectors([0.0, 0.0, 1.0], np.asarray(shaft_camera, dtype=float))
    return rotation.as_matrix()


def trocar_from_imu(chain: ChainCalibration, earth_from_imu) -> np.ndarray:
    """(4, 4) IMU to trocar at one IMU orientation (3, 3) or Rotation: the lever to the pivot, turned (Fig 8B)."""
    rotation = chain.trocar_from_earth[:3, :3] @ _orientation(earth_from_imu)
    return make_transform(rotation, -rotation @ chain.pivot_imu_mm)


def trocar_from_camera(chain: ChainCalibration, earth_from_imu) -> np.ndarray:
    """(4, 4) camera to trocar at one IMU orientation: ``trocar_from_imu(t) @ imu_from_camera``."""
    return trocar_from_imu(chain, earth_from_imu) @ chain.imu_from_camera


def camera_from_probe(tip_camera: np.ndarray, axis_camera: np.ndarray) -> np.ndarray:
    """(4, 4) probe to camera from a tracked tip (3,) mm and unit axis (3,), both in the camera frame.

    The probe frame has its origin at the tip and z along the axis from the tip backwards (towards the stripes,
    as tracking reports it). Roll about the axis is not observable (the stripes are rings), so x is the camera
    axis least aligned with the probe, made perpendicular to it: a fixed, continuous choice away from the switch.
    """
    tip, axis = np.asarray(tip_camera, dtype=float), np.asarray(axis_camera, dtype=float)
    if tip.shape != (3,) or axis.shape != (3,) or not (np.isfinite(tip).all() and np.isfinite(axis).all()):
        raise ValueError(f"a probe pose needs a finite tip (3,) and axis (3,), got shapes {tip.shape} and {axis.shape}")
    z = axis / np.linalg.norm(axis)
    reference = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = reference - (reference @ z) * z
    x /= np.linalg.norm(x)
    return make_transform(np.column_stack([x, np.cross(z, x), z]), tip)


def trocar_from_probe(chain: ChainCalibration, earth_from_imu, camera_from_probe: np.ndarray) -> np.ndarray:
    """(4, 4) probe to trocar: :func:`trocar_from_camera` composed with the tracked ``camera_from_probe`` (4, 4)."""
    return trocar_from_camera(chain, earth_from_imu) @ _rigid(camera_from_probe, "camera_from_probe")


def camera_to_trocar(chain: ChainCalibration, earth_from_imu, points_camera: np.ndarray) -> np.ndarray:
    """Points (N, 3) or (3,) mm from the camera to the trocar frame, all seen at one IMU orientation."""
    points = np.asarray(points_camera, dtype=float)
    if points.shape[-1:] != (3,) or points.ndim > 2:
        raise ValueError(f"points must have shape (N, 3) or (3,), got {points.shape}")
    if not np.isfinite(points).all():
        raise ValueError("points contain NaN or infinite values")
    return apply(trocar_from_camera(chain, earth_from_imu), points.reshape(-1, 3)).reshape(points.shape)


def _orientation(earth_from_imu) -> np.ndarray:
    """(3, 3) rotation from a scipy Rotation or a (3, 3) / (4, 4) array; rejects non-rotations."""
    if isinstance(earth_from_imu, Rotation):
        if not earth_from_imu.single:
            raise ValueError(f"expected one IMU orientation, got {len(earth_from_imu)}")
        return earth_from_imu.as_matrix()
    matrix = np.asarray(earth_from_imu, dtype=float)
    if matrix.shape not in ((3, 3), (4, 4)):
        raise ValueError(f"an IMU orientation must be a (3, 3) rotation or a scipy Rotation, got shape {matrix.shape}")
    return _rigid(make_transform(matrix[:3, :3], np.zeros(3)), "the IMU orientation")[:3, :3]


def _close(a: np.ndarray, b: np.ndarray, atol: float) -> bool:
    """``np.allclose(a, b, atol=atol)`` (rtol 1e-5) for finite ``a``, without its wrapper's cost: the chain checks
    its transforms several times per live pair (issue 36), where ``allclose`` took most of the check."""
    return bool((np.abs(a - b) <= atol + 1e-5 * np.abs(b)).all())


def _rigid(transform: np.ndarray, name: str) -> np.ndarray:
    """A read-only float (4, 4) copy of a rigid transform; ``ValueError`` naming ``name`` otherwise."""
    matrix = np.array(transform, dtype=float)
    if matrix.shape != (4, 4):
        raise ValueError(f"{name} must be a 4x4 transform, got shape {matrix.shape}")
    rotation = matrix[:3, :3]
    if (not np.isfinite(matrix).all() or not _close(matrix[3], _LAST_ROW, 1e-8)
            or not _close(rotation @ rotation.T, _EYE3, _ORTHONORMAL_TOL)
            or np.linalg.det(rotation) < 0):
        raise ValueError(f"{name} is not a rigid transform (rotation with determinant +1, last row 0 0 0 1)")
    matrix.setflags(write=False)
    return matrix
