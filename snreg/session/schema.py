"""The session file's schema (docs/design.md, Contracts "Session (HDF5)"): names, versions, stream tables, validation.

Everything a session stores is pseudonymous: the only identifier is ``case_id``, checked here so that a
patient name or birth date typed by mistake is refused before anything reaches the disk.
"""

from __future__ import annotations

import hashlib
import json
import re
from dataclasses import dataclass, field

import cv2
import numpy as np

from snreg.camera import StereoCalibration
from snreg.errors import SessionError
from snreg.landmarks import NODE
from snreg.registration import RegistrationResult

FORMAT = "snreg-session"
FORMAT_VERSION = 5      # 2: nodes carry earth_from_imu and the calibration versions; an ``events`` log (1 reads)
                        # 3: Fletcher-32 on every fixed-size dataset, digests of the variable-length data, ``videos``
                        # 4: ``streams/camera`` (the tracked insertion) and each node's ``trocar_camera_mm``. Bumped
                        # because a format-3 reader would ignore both: its retrack or re-expression would map nodes
                        # stored with a tracked insertion through the chain's constant distance, and resuming the
                        # file would leave the node column short; a format-3 reader refuses a format-4 file instead.
                        # Still 4 (unreleased when it came): each node's ``cov_trocar_mm2``, NaN when not stored.
                        # 5: intraop points of kind ``landmark`` beside the nodes (``nodes/intraop/kind``), preop
                        # landmarks (``nodes/preop/landmarks``), registrations' landmark residuals. Bumped because a
                        # format-4 reader would take a stored landmark for a node and register it as one.
                        # Still 5 (unreleased when it came): the preop nodes' ``patient_position``, ``table_tilt_deg``
                        # and ``tilt_entered`` attributes (absent: unknown).
JOURNAL_SUFFIX = ".journal"

_CASE_ID = re.compile(r"[A-Za-z0-9._-]{1,64}")
_DATE = re.compile(r"(19|20)\d{2}[-._]?\d{2}[-._]?\d{2}|\d{2}[-._]\d{2}[-._](19|20)\d{2}")
_NAME_YEAR = re.compile(r"[A-Z][a-z]{2,}[-._]?(19|20)\d{2}(?!\d)")     # "Smith1960", "Doe_1972": name and birth year

# Stream tables: host time (time.perf_counter_ns, monotonic, as docs/design.md, Conventions) and device time, both ns.
# imu: device time = the sensor's microsecond clock x 1000. probe and frames: the cameras have no device clock,
# so t_host_ns is the left eye's grab time and t_device_ns the right eye's, both on the host clock (their
# difference is the left/right skew). camera (format 4): one row per pair while the insertion is tracked, on the
# frames' clock as probe; ``trocar_camera_mm`` the tracker's insertion (NaN when lost), ``state`` a code of
# CAMERA_STATES, ``quality``, ``residual_mm`` and ``sd_mm`` as :class:`snreg.odometry.InsertionEstimate` has them.
STREAM_DTYPES = {
    "imu": np.dtype([("t_host_ns", "<i8"), ("t_device_ns", "<i8"), ("acc_g", "<f4", (3,)),
                     ("gyro_dps", "<f4", (3,))]),
    "probe": np.dtype([("t_host_ns", "<i8"), ("t_device_ns", "<i8"), ("tip_mm", "<f4", (3,)),
                       ("centre_mm", "<f4", (3,)), ("axis", "<f4", (3,)), ("quality", "<f4")]),
    "frames": np.dtype([("t_host_ns", "<i8"), ("t_device_ns", "<i8"), ("index", "<i8")]),
    "camera": np.dtype([("t_host_ns", "<i8"), ("t_device_ns", "<i8"), ("trocar_camera_mm", "<f8"), ("state", "u1"),
                        ("quality", "<f4"), ("residual_mm", "<f4"), ("sd_mm", "<f4")]),
}
STREAM_SINCE = {"camera": 4}            # streams added after format 3: absent from older files, they read as empty
CAMERA_STATES = ("lost", "tracked")     # streams/camera ``state``: the code is the index


def validate_case_id(case_id: str) -> str:
    """Return ``case_id`` if it is a pseudonym: 1-64 of ``A-Z a-z 0-9 . _ -``, nothing like a date or a capitalised
    name followed by a year; else SessionError saying why (the new-session dialog shows it as the id is typed)."""
    text = str(case_id)
    if not _CASE_ID.fullmatch(text):
        raise SessionError(f"case id {text!r} is refused: use a pseudonymous id of 1 to 64 letters, digits, '.', '_' "
                           "or '-' (no spaces, no patient names)")
    if _DATE.search(text):
        raise SessionError(f"case id {text!r} is refused: it looks like a date; use a pseudonymous id without "
                           "birth dates")
    if _NAME_YEAR.search(text):
        raise SessionError(f"case id {text!r} is refused: it looks like a name with a year of birth; use a "
                           "pseudonymous id")
    return text


@dataclass(frozen=True, eq=False)
class IntraopNode:
    """One stored sentinel node: positions in mm (trocar and left-camera frames), time in ns (host clock).

    ``spread_mm`` is the scatter of the tip over the ``n_frames`` averaged; ``counts`` the gamma probe
    reading (NaN when none); the snapshots are JPEG bytes (empty when none). What the node was measured with,
    so it can be re-expressed when a calibration changes: ``earth_from_imu`` (3, 3) the mean IMU orientation over
    its fixes (NaN when unknown: files of format 1), ``stereo_version`` and ``chain_version`` the
    :func:`calibration_version` of the stereo calibration and chain that mapped it ("" when unknown);
    ``trocar_camera_mm`` the camera's insertion it was mapped with, the median over its fixes while the insertion was
    tracked (NaN when unknown: tracking off, or files before format 4; the chain's own distance then mapped it);
    ``cov_trocar_mm2`` (3, 3) its own error's covariance in the trocar frame (:mod:`snreg.tracking.uncertainty`; NaN
    when unknown: files written before it was stored, or nodes stored without the acquisition). ``kind``: ``node``, or
    ``landmark`` for an anatomical landmark touched with the probe (format 5), whose ``id`` is its name: stored,
    re-expressed and exported as a node is, but never counted, paired or registered as one.
    """

    id: str
    label: str
    time_ns: int
    xyz_trocar: np.ndarray
    xyz_camera: np.ndarray
    spread_mm: float
    n_frames: int
    counts: float
    left_jpeg: bytes = b""
    right_jpeg: bytes = b""
    earth_from_imu: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    stereo_version: str = ""
    chain_version: str = ""
    trocar_camera_mm: float = float("nan")
    cov_trocar_mm2: np.ndarray = field(default_factory=lambda: np.full((3, 3), np.nan))
    kind: str = NODE

    def to_json(self) -> dict:
        """JSON-ready, the snapshots as hex (the journal's form)."""
        return {"id": self.id, "label": self.label, "time_ns": int(self.time_ns),
                "xyz_trocar": [float(v) for v in self.xyz_trocar], "xyz_camera": [float(v) for v in self.xyz_camera],
                "spread_mm": float(self.spread_mm), "n_frames": int(self.n_frames), "counts": float(self.counts),
                "left_jpeg": self.left_jpeg.hex(), "right_jpeg": self.right_jpeg.hex(),
                "earth_from_imu": np.asarray(self.earth_from_imu, dtype=float).tolist(),
                "stereo_version": self.stereo_version, "chain_version": self.chain_version,
                "trocar_camera_mm": float(self.trocar_camera_mm),
                "cov_trocar_mm2": covariance_json(self.cov_trocar_mm2), "kind": self.kind}

    @classmethod
    def from_json(cls, data: dict) -> "IntraopNode":
        return cls(str(data["id"]), str(data["label"]), int(data["time_ns"]),
                   np.asarray(data["xyz_trocar"], dtype=float), np.asarray(data["xyz_camera"], dtype=float),
                   float(data["spread_mm"]), int(data["n_frames"]), float(data["counts"]),
                   bytes.fromhex(data["left_jpeg"]), bytes.fromhex(data["right_jpeg"]),
                   np.asarray(data.get("earth_from_imu", np.full((3, 3), np.nan)), dtype=float).reshape(3, 3),
                   str(data.get("stereo_version", "")), str(data.get("chain_version", "")),
                   float(data.get("trocar_camera_mm", float("nan"))), covariance_mm2(data.get("cov_trocar_mm2")),
                   str(data.get("kind", NODE)))

    @property
    def measured_under(self) -> tuple[str, str]:
        """(stereo_version, chain_version): the calibration this node's trocar position was mapped with."""
        return self.stereo_version, self.chain_version


@dataclass(frozen=True, eq=False)
class StoredRegistration:
    """A registration as the session keeps it: ``n`` (its number), the result, the ids of the preop and intraop nodes
    it paired, in the order the result indexes them (None in files written before ids were stored), and whether it
    is the one marked final."""

    n: int
    result: RegistrationResult
    preop_ids: list[str] | None
    intraop_ids: list[str] | None
    final: bool = False

    @classmethod
    def from_json(cls, data: dict, final: bool = False) -> "StoredRegistration":
        def optional(key, dtype=float):
            return None if data.get(key) is None else np.asarray(data[key], dtype=dtype)

        result = RegistrationResult(data["method"], np.asarray(data["transform"]), np.asarray(data["pairing"], dtype=int),
                                    np.asarray(data["distances_mm"]), float(data["rms_mm"]),
                                    np.asarray(data["confidence"]), data["pairing_rule"], initial=optional("initial"),
                                    target_error_mm=optional("target_error_mm"), missing=optional("missing", bool),
                                    leave_one_out_mm=optional("leave_one_out_mm"),
                                    **landmark_results(data.get("landmarks")))
        return cls(int(data["n"]), result, data.get("preop_ids"), data.get("intraop_ids"), final)


def landmark_results(data: dict | None) -> dict:
    """A registration's landmark fields from their stored form (``{"residual_mm", "leave_one_out_mm", "suspect"}``;
    None: no landmarks, or a file before format 5)."""
    data = data or {}
    return {"landmark_residual_mm": {str(k): float(v) for k, v in data.get("residual_mm", {}).items()},
            "landmark_leave_one_out_mm": {str(k): float(v) for k, v in data.get("leave_one_out_mm", {}).items()},
            "landmarks_suspect": [str(name) for name in data.get("suspect", [])]}


def landmark_results_json(result) -> dict | None:
    """The stored form of a result's landmark fields (:func:`landmark_results`); None when it had no landmarks."""
    residual = getattr(result, "landmark_residual_mm", None) or {}
    if not residual and not getattr(result, "landmarks_suspect", None):
        return None
    return {"residual_mm": {k: float(v) for k, v in residual.items()},
            "leave_one_out_mm": {k: float(v) for k, v in (result.landmark_leave_one_out_mm or {}).items()},
            "suspect": [str(name) for name in result.landmarks_suspect]}


def covariance_mm2(value) -> np.ndarray:
    """A node's (3, 3) covariance in mm^2 from its JSON form; NaN (unknown) for None."""
    return np.full((3, 3), np.nan) if value is None else np.asarray(value, dtype=float).reshape(3, 3)


def covariance_json(covariance) -> list | None:
    """A node's covariance in JSON form: nested lists (mm^2), None when unknown (not finite)."""
    matrix = np.asarray(covariance, dtype=float).reshape(3, 3)
    return matrix.tolist() if np.all(np.isfinite(matrix)) else None


def position_mm(value) -> np.ndarray:
    """A (3,) position in mm; :class:`SessionError` for anything else."""
    vec = np.asarray(value, dtype=float).reshape(-1)
    if vec.shape != (3,):
        raise SessionError(f"a node position needs 3 coordinates in mm, got {vec.size}")
    return vec


def jpeg_bytes(image) -> bytes:
    """JPEG bytes as given, or an image (H, W[, 3]) uint8 encoded with ``cv2.imencode``."""
    if isinstance(image, (bytes, bytearray)):
        return bytes(image)
    image = np.asarray(image)
    if image.ndim == 1:
        return image.astype(np.uint8).tobytes()
    ok, buf = cv2.imencode(".jpg", image)
    if not ok:
        raise SessionError("a node snapshot could not be encoded as JPEG; pass a uint8 image (H, W[, 3])")
    return buf.tobytes()


def stereo_to_dict(calib) -> dict:
    """A :class:`~snreg.camera.StereoCalibration` in JSON form: matrices as nested lists."""
    out = {"image_size": [int(v) for v in calib.image_size]}
    for key in ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q"):
        out[key] = np.asarray(getattr(calib, key), dtype=float).tolist()
    for key in ("rms_reprojection_px", "board_cols", "board_rows", "square_mm", "n_views", "created_utc", "snreg_version"):
        out[key] = getattr(calib, key)
    return out


def stereo_from_dict(data: dict):
    """Inverse of :func:`stereo_to_dict`."""
    data = dict(data)
    size = tuple(int(v) for v in data.pop("image_size"))
    return StereoCalibration(size, **{k: np.asarray(v) if isinstance(v, list) else v for k, v in data.items()})


_VERSIONED = ("image_size", "K1", "D1", "K2", "D2", "R", "T",            # stereo: the camera model itself
              "imu_from_camera", "imu_trocar_mm", "trocar_from_earth")      # chain


def calibration_version(data: dict | None) -> str:
    """A short content hash (8 hex digits) of a calibration in its JSON form (:func:`stereo_to_dict`,
    ``ChainCalibration.to_dict``) over the values that move a tip (not its date or quality figures), rounded to
    1e-9: the same calibration gives the same version in any session and after any file round trip; "" for none."""
    if data is None:
        return ""
    values = {key: (np.round(np.asarray(data[key], dtype=float), 9) + 0.0).tolist()   # + 0.0: no -0.0
              for key in _VERSIONED if key in data}
    text = json.dumps(values, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:8]
