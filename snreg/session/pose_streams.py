"""The rig's pose over a recorded session, from its streams: the IMU orientation and the camera's insertion at any
host time.

Why here: the probe pose export (:mod:`.slicer_sequence`) and re-tracking (:mod:`snreg.workflow.retrack`) map
recorded fixes again and must do it as the live acquisition did. The orientation: the stored IMU samples fused again
with the live filter (:func:`~snreg.session.timeline.fuse_imu`), slerped at each time. The insertion: the live
acquisition mapped each pair with the insertion tracked at that pair, a lost pair with the last one tracked before it,
and every pair before the first tracked one with the tracker's start (the chain's distance); ``streams/camera`` holds
the tracker's values, so :func:`insertions_at` reads them back that way. A session recorded with tracking off, or
of format 3 (no camera stream), reads as the chain's constant distance throughout.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from snreg.session.schema import CAMERA_STATES
from snreg.session.timeline import ImuSeries, fuse_imu

__all__ = ["orientations_at", "insertions_at", "tracked_rows"]

_TRACKED = CAMERA_STATES.index("tracked")


def orientations_at(imu: np.ndarray, t_ns: np.ndarray) -> tuple[np.ndarray, str]:
    """(N, 3, 3) ``earth_from_imu`` at each host time ``t_ns`` (N,) ns from ``streams/imu`` rows: the fused samples,
    slerped, held at their ends; and how they were got, in words (no samples: level assumed, the identity)."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    if len(imu) == 0:
        return np.repeat(np.eye(3)[None], len(t_ns), axis=0), "none recorded: level assumed (identity)"
    t_imu = np.asarray(imu["t_host_ns"], dtype=np.int64)
    series = ImuSeries((t_imu - t_imu[0]) / 1e9, np.asarray(imu["t_device_ns"] // 1000, dtype=np.int64),
                       np.asarray(imu["acc_g"], dtype=float), np.asarray(imu["gyro_dps"], dtype=float))
    rotations = Rotation.from_euler("ZYX", fuse_imu(series), degrees=True)
    keep = np.r_[np.diff(t_imu) > 0, True]              # strictly increasing times for the slerp: last of equals
    t_imu, rotations = t_imu[keep], rotations[keep]
    source = "the stored IMU samples fused again (live filter), slerped at each fix's host time"
    if len(t_imu) == 1:
        return np.repeat(rotations.as_matrix(), len(t_ns), axis=0), source
    at = np.clip(t_ns, t_imu[0], t_imu[-1])
    return Slerp((t_imu - t_imu[0]) / 1e9, rotations)((at - t_imu[0]) / 1e9).as_matrix(), source


def tracked_rows(camera: np.ndarray) -> np.ndarray:
    """(n,) bool: the ``streams/camera`` rows whose insertion was tracked (a number, not lost)."""
    return (np.asarray(camera["state"]) == _TRACKED) & np.isfinite(np.asarray(camera["trocar_camera_mm"]))


def insertions_at(camera: np.ndarray, t_ns: np.ndarray, start_mm: float) -> np.ndarray:
    """(N,) mm: the insertion each host time ``t_ns`` (N,) ns was mapped with live, from ``streams/camera`` rows: the
    last tracked row at or before it; ``start_mm`` (the chain's distance) before any, and throughout when no row
    was tracked (tracking off, or a file of format 3)."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    tracked = tracked_rows(camera) if len(camera) else np.zeros(0, bool)
    if not tracked.any():
        return np.full(len(t_ns), float(start_mm))
    times = np.asarray(camera["t_host_ns"], dtype=np.int64)[tracked]
    values = np.asarray(camera["trocar_camera_mm"], dtype=float)[tracked]
    order = np.argsort(times, kind="stable")
    times, values = times[order], values[order]
    k = np.searchsorted(times, t_ns, side="right") - 1
    return np.where(k >= 0, values[np.maximum(k, 0)], float(start_mm))
