"""Reading the HDF5 side of a session: the tables as written by :mod:`.writer` (the header and damage are
:mod:`.opening`'s and :mod:`.salvage`'s)."""

from __future__ import annotations

import json

import h5py
import numpy as np

from snreg.landmarks import NODE
from snreg.session.schema import IntraopNode

HEADER_KEYS = ("format", "format_version", "created_utc", "snreg_version", "case_id")
_DOWN_KEYS = ("patient_position", "table_tilt_deg", "tilt_entered")     # nodes/preop's, as PreopDown.to_json has them


def read_nodes(h5: h5py.File) -> list[IntraopNode]:
    """Every complete row of ``nodes/intraop`` (a row cut short by a kill is dropped)."""
    group = h5["nodes/intraop"]
    cols = {name: group[name][()] for name in group}
    n = min(len(v) for v in cols.values())
    unknown = np.full((3, 3), np.nan)          # format 1: no orientation or calibration versions stored
    # format 3 and before: no insertion stored (NaN: the chain's own distance mapped the node); files written before
    # the nodes' covariances were stored: NaN (unknown)
    return [IntraopNode(_plain(cols["id"][k]), _plain(cols["label"][k]), int(cols["time_ns"][k]),
                        cols["xyz_trocar"][k], cols["xyz_camera"][k], float(cols["spread_mm"][k]),
                        int(cols["n_frames"][k]), float(cols["counts"][k]), bytes(cols["left_jpeg"][k]),
                        bytes(cols["right_jpeg"][k]),
                        cols["earth_from_imu"][k] if "earth_from_imu" in cols else unknown.copy(),
                        _plain(cols["stereo_version"][k]) if "stereo_version" in cols else "",
                        _plain(cols["chain_version"][k]) if "chain_version" in cols else "",
                        float(cols["trocar_camera_mm"][k]) if "trocar_camera_mm" in cols else float("nan"),
                        cols["cov_trocar_mm2"][k] if "cov_trocar_mm2" in cols else unknown.copy(),
                        _plain(cols["kind"][k]) if "kind" in cols else NODE)     # before format 5: nodes only
            for k in range(n)]


def read_events(h5: h5py.File) -> list[dict]:
    """The ``events`` log, oldest first (empty in format-1 files); a row cut short by a kill is skipped."""
    if "events" not in h5:
        return []
    out = []
    for raw in h5["events"][()]:
        try:
            out.append(json.loads(_plain(raw)))
        except ValueError:
            continue
    return out


def read_calibration(group: h5py.Group) -> dict:
    """One ``calibration/<kind>`` group in the journal's JSON form (matrices as lists, scalars from attributes)."""
    data = {key: _plain(value) for key, value in group.attrs.items()}
    data.update({key: ds[()].tolist() for key, ds in group.items()})
    return data


def read_video(group: h5py.Group) -> dict:
    """One ``videos/<n>`` group's attributes in the journal's JSON form (none in files before format 3)."""
    return {key: [_plain(v) for v in value.tolist()] if isinstance(value, np.ndarray) else _plain(value)
            for key, value in group.attrs.items()}


def numbered_names(group: h5py.Group) -> list[str]:
    """The members of a group of numbered parts (``registration``, ``videos``) in number order; any member whose name
    is not a number after them, so a damaged name is seen and left out by the caller rather than sorted wrongly."""
    return sorted(group, key=lambda name: (not name.isdigit(), int(name) if name.isdigit() else 0, name))


def read_preop(h5: h5py.File) -> dict | None:
    group = h5["nodes/preop"]
    if "id" not in group:
        return None
    return {"ids": [_plain(v) for v in group["id"][()]], "labels": [_plain(v) for v in group["label"][()]],
            "xyz": group["xyz"][()].tolist(), "counts": group["counts"][()].tolist() if "counts" in group else None,
            "frame": _plain(group.attrs.get("frame", "")),
            "cov": group["cov_mm2"][()].tolist() if "cov_mm2" in group else None,     # absent: none stored
            "down": ({key: _plain(group.attrs[key]) for key in _DOWN_KEYS}              # absent: unknown
                     if all(key in group.attrs for key in _DOWN_KEYS) else None),
            "landmarks": _preop_landmarks(group)}


def _preop_landmarks(group: h5py.Group) -> dict | None:
    """``nodes/preop/landmarks`` in the journal's JSON form; None when absent (none stored, or before format 5)."""
    if "landmarks" not in group:
        return None
    marks = group["landmarks"]
    return {"ids": [_plain(v) for v in marks["id"][()]], "labels": [_plain(v) for v in marks["label"][()]],
            "xyz": marks["xyz"][()].tolist()}


def read_registration(group: h5py.Group, n: int) -> dict:
    """``registration/<n>`` in the journal's JSON form."""
    data = {key: group[key][()].tolist() for key in ("transform", "pairing", "distances_mm", "confidence")}
    data.update({key: _plain(group.attrs[key]) for key in ("method", "rms_mm", "pairing_rule")}, n=n)
    for key in ("preop_ids", "intraop_ids"):       # absent in files written before they were stored
        data[key] = [_plain(v) for v in group[key][()]] if key in group else None
    for key in ("initial", "target_error_mm", "leave_one_out_mm", "missing"):   # absent in older files
        data[key] = group[key][()].tolist() if key in group else None
    data["final"] = bool(group.attrs.get("final", False))          # absent: not final (older files: none is)
    data["landmarks"] = json.loads(_plain(group.attrs["landmarks"])) if "landmarks" in group.attrs else None
    return data


def readable_rows(dataset: h5py.Dataset, block: int = 4096) -> np.ndarray:
    """The rows of a stream table up to the first unreadable block (for recovery)."""
    parts = []
    for start in range(0, dataset.shape[0], block):
        try:
            parts.append(dataset[start:start + block])
        except (OSError, ValueError, RuntimeError):
            break
    return np.concatenate(parts) if parts else np.zeros(0, dataset.dtype)


def _plain(value):
    if isinstance(value, bytes):
        return value.decode("utf-8")
    if isinstance(value, np.generic):
        return value.item()
    return value
