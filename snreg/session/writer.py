"""Writing the HDF5 side of a session: groups, resizable tables, and buffered streams.

Streams (IMU at 208 Hz, probe at 30 Hz, frame times) are buffered and appended in chunks about once a
second, so an hour never sits in memory; a kill loses at most the last unflushed second of them.

Integrity (format 3): every fixed-size dataset carries HDF5's Fletcher-32 checksum. HDF5 refuses filters on
variable-length data (strings, the snapshot JPEGs: their bytes live in the global heap), so those carry SHA-256
digests instead: a ``digest`` column in ``nodes/intraop`` (one per variable-length field of the row), an ``events_digest``
row per event, and a ``sha256`` attribute on each variable-length dataset written once (ids, labels).
"""

from __future__ import annotations

import hashlib
import json
import time

import h5py
import numpy as np

from snreg.registration.pairing import shared
from snreg.session.schema import FORMAT_VERSION, STREAM_DTYPES, IntraopNode

_BYTES = h5py.vlen_dtype(np.uint8)
_STR = h5py.string_dtype()
_NODE_FIELDS = {"id": _STR, "label": _STR, "time_ns": "<i8", "xyz_trocar": ("<f8", (3,)), "xyz_camera": ("<f8", (3,)),
                "spread_mm": "<f8", "n_frames": "<i8", "counts": "<f8", "left_jpeg": _BYTES, "right_jpeg": _BYTES,
                # format 2: what the node was measured with (a format-1 file gets these columns when resumed)
                "earth_from_imu": ("<f8", (3, 3)), "stereo_version": _STR, "chain_version": _STR,
                # format 3: SHA-256 (hex) of each of the row's variable-length fields (DIGESTED), which Fletcher-32
                # cannot cover
                "digest": ("S64", (6,)),
                # format 4: the insertion the node was mapped with (NaN: untracked) and the node's own error's
                # covariance, mm^2, trocar frame (NaN: unknown)
                "trocar_camera_mm": "<f8", "cov_trocar_mm2": ("<f8", (3, 3)),
                # format 5: node | landmark (fixed length, so Fletcher-32 covers it)
                "kind": "S8"}
_FILL = {"earth_from_imu": np.nan, "stereo_version": "", "chain_version": "", "digest": b"", "trocar_camera_mm": np.nan,
         "cov_trocar_mm2": np.nan, "kind": b"node"}
DIGESTED = ("id", "label", "left_jpeg", "right_jpeg", "stereo_version", "chain_version")   # the digest's columns
CHECKED = {"fletcher32": True}        # every fixed-size dataset: HDF5 verifies its chunks on every read


def row_digest(values) -> bytes:
    """SHA-256 (hex, bytes) of a row's variable-length values (str or bytes), each length-prefixed."""
    digest = hashlib.sha256()
    for value in values:
        data = value.encode("utf-8") if isinstance(value, str) else bytes(value)
        digest.update(len(data).to_bytes(8, "little") + data)
    return digest.hexdigest().encode("ascii")


def _variable(group, name: str, values: list[str]) -> None:
    """A write-once variable-length string dataset with the ``sha256`` attribute of its values."""
    group.create_dataset(name, data=np.array(values, dtype=object), dtype=_STR)
    group[name].attrs["sha256"] = row_digest(values).decode("ascii")


def init_file(h5: h5py.File, header: dict) -> None:
    """Root attributes and the empty groups and tables of a new session."""
    for key, value in header.items():
        h5.attrs[key] = value
    for group in ("calibration", "nodes/preop", "registration", "nodes/intraop"):
        h5.require_group(group)
    require_tables(h5)


def require_tables(h5: h5py.File) -> None:
    """Every stream table, every ``nodes/intraop`` table and the ``events`` log, adding what an older file lacks
    (existing node rows get NaN or "" there, a new stream is empty) and marking the file of the current format."""
    for name, dtype in STREAM_DTYPES.items():
        if f"streams/{name}" not in h5:
            h5.create_dataset(f"streams/{name}", shape=(0,), maxshape=(None,), dtype=dtype, chunks=(1024,),
                              compression="gzip", compression_opts=1, **CHECKED)
    intraop = h5["nodes/intraop"]
    n = intraop["id"].shape[0] if "id" in intraop else 0
    for name, dtype in _NODE_FIELDS.items():
        if name in intraop:
            continue
        base, shape = dtype if isinstance(dtype, tuple) else (dtype, ())
        dataset = intraop.create_dataset(name, shape=(n, *shape), maxshape=(None, *shape), dtype=base,
                                         chunks=(16, *shape), **({} if base in (_STR, _BYTES) else CHECKED))
        if n and name in _FILL:
            dataset[...] = _FILL[name]
    if "events" not in h5:
        h5.create_dataset("events", shape=(0,), maxshape=(None,), dtype=_STR, chunks=(64,))
    if "events_digest" not in h5:                # older files: their events are digested as they stand
        texts = [_text(raw) for raw in h5["events"][()]]
        h5.create_dataset("events_digest", data=np.array([row_digest([t]) for t in texts], dtype="S64"),
                          maxshape=(None,), chunks=(64,), **CHECKED)
    h5.require_group("videos")
    h5.attrs["format_version"] = FORMAT_VERSION


def _text(raw) -> str:
    return raw.decode("utf-8") if isinstance(raw, bytes) else str(raw)


def write_video(h5: h5py.File, segment: dict) -> None:
    """``videos/<n>``: one recorded segment's attributes (files, first frame row, rate, size, codec; once closed its
    frames, sizes and SHA-256 per side). Rewritten when the segment closes."""
    group = h5["videos"].require_group(str(segment["n"]))
    for key, value in segment.items():
        group.attrs[key] = value


def append_event(h5: h5py.File, event: dict) -> None:
    """One row of the ``events`` log: the event as a JSON object (refused stores, re-expressions, acquisition starts)."""
    events, digests = h5["events"], h5["events_digest"]
    n = events.shape[0]
    text = json.dumps(event, separators=(",", ":"), allow_nan=True)
    events.resize(n + 1, axis=0)
    events[n] = text
    digests.resize(n + 1, axis=0)
    digests[n] = row_digest([text])


def write_node(h5: h5py.File, node: IntraopNode) -> None:
    """Append one row to every ``nodes/intraop`` table."""
    intraop = h5["nodes/intraop"]
    n = intraop["id"].shape[0]
    values = {"id": node.id, "label": node.label, "time_ns": node.time_ns, "xyz_trocar": node.xyz_trocar,
              "xyz_camera": node.xyz_camera, "spread_mm": node.spread_mm, "n_frames": node.n_frames,
              "counts": node.counts, "left_jpeg": np.frombuffer(node.left_jpeg, np.uint8),
              "right_jpeg": np.frombuffer(node.right_jpeg, np.uint8), "earth_from_imu": node.earth_from_imu,
              "stereo_version": node.stereo_version, "chain_version": node.chain_version,
              "trocar_camera_mm": node.trocar_camera_mm, "cov_trocar_mm2": node.cov_trocar_mm2,
              "kind": node.kind.encode("ascii")}
    values["digest"] = [row_digest([values[name]]) for name in DIGESTED]
    for name, value in values.items():
        intraop[name].resize(n + 1, axis=0)
        intraop[name][n] = value


def rewrite_nodes(h5: h5py.File, nodes: list[IntraopNode]) -> None:
    """Replace every ``nodes/intraop`` row with ``nodes`` (after an undo, or to catch up with the journal)."""
    for dataset in h5["nodes/intraop"].values():
        dataset.resize(0, axis=0)
    for node in nodes:
        write_node(h5, node)


def write_calibration(h5: h5py.File, kind: str, data: dict) -> None:
    """``calibration/stereo`` or ``calibration/chain``: each matrix a dataset under its own name, scalars attributes."""
    if kind in h5["calibration"]:
        del h5["calibration"][kind]
    group = h5["calibration"].create_group(kind)
    for key, value in data.items():
        if isinstance(value, list):
            group.create_dataset(key, data=np.asarray(value, dtype=float), **CHECKED)
        else:
            group.attrs[key] = value


def write_preop(h5: h5py.File, data: dict) -> None:
    """``nodes/preop``: ids, labels, xyz (N, 3) mm, counts (N,) and ``cov_mm2`` (N, 3, 3, each hot spot's own error
    in the set's frame) when known; the frame as an attribute; the preop landmarks, when given, in
    ``nodes/preop/landmarks`` (id = name, label, xyz (L, 3) mm, in the nodes' frame); when known what gives the down
    in that frame (:class:`~snreg.preop.gravity.PreopDown`: attributes ``patient_position``, ``table_tilt_deg``,
    ``tilt_entered``)."""
    del h5["nodes/preop"]
    group = h5.create_group("nodes/preop")
    _variable(group, "id", [str(v) for v in data["ids"]])
    _variable(group, "label", [str(v) for v in data["labels"]])
    group.create_dataset("xyz", data=np.asarray(data["xyz"], dtype=float).reshape(-1, 3), **CHECKED)
    if data["counts"] is not None:
        group.create_dataset("counts", data=np.asarray(data["counts"], dtype=float), **CHECKED)
    if data.get("cov") is not None:
        group.create_dataset("cov_mm2", data=np.asarray(data["cov"], dtype=float).reshape(-1, 3, 3), **CHECKED)
    group.attrs["frame"] = data["frame"]
    for key, value in (data.get("down") or {}).items():     # PreopDown.to_json: patient position and table tilt
        group.attrs[key] = value
    marks = data.get("landmarks")
    if marks is not None:
        landmarks = group.create_group("landmarks")
        _variable(landmarks, "id", [str(v) for v in marks["ids"]])
        _variable(landmarks, "label", [str(v) for v in marks["labels"]])
        landmarks.create_dataset("xyz", data=np.asarray(marks["xyz"], dtype=float).reshape(-1, 3), **CHECKED)


def write_registration(h5: h5py.File, data: dict) -> None:
    """``registration/<n>``: transform (4, 4) intraop_from_preop, pairing (the hot spot each intraop node came from,
    -1 for none), shares (another node came from the same hot spot), distances (mm), confidence, the ids of the preop
    and intraop nodes paired; when known the initial alignment (4, 4), the target-error bounds and missing flags (per
    preop node) and the leave-one-out distances (per intraop node); method, RMS as attributes; with landmarks, their
    residuals, leave-one-out residuals and suspects as the JSON attribute ``landmarks``."""
    group = h5["registration"].create_group(str(data["n"]))
    for key in ("transform", "pairing", "distances_mm", "confidence"):
        group.create_dataset(key, data=np.asarray(data[key], dtype=int if key == "pairing" else float), **CHECKED)
    group.create_dataset("shares", data=shared(data["pairing"]), **CHECKED)
    for key in ("preop_ids", "intraop_ids"):
        if data.get(key) is not None:
            _variable(group, key, [str(v) for v in data[key]])
    for key in ("initial", "target_error_mm", "leave_one_out_mm"):
        if data.get(key) is not None:
            group.create_dataset(key, data=np.asarray(data[key], dtype=float), **CHECKED)
    if data.get("missing") is not None:
        group.create_dataset("missing", data=np.asarray(data["missing"], dtype=bool), **CHECKED)
    for key in ("method", "rms_mm", "pairing_rule"):
        group.attrs[key] = data[key]
    if data.get("landmarks") is not None:
        group.attrs["landmarks"] = json.dumps(data["landmarks"], allow_nan=True)


def write_final(h5: h5py.File, n: int | None) -> None:
    """Attribute ``final=True`` on ``registration/<n>`` and on no other (None: on none); a registration group not in
    the file yet (only in the journal) is skipped. Touches attributes only, never a table."""
    for name, group in h5["registration"].items():
        if n is not None and int(name) == n:
            group.attrs["final"] = True
        elif "final" in group.attrs:
            del group.attrs["final"]


class StreamBuffer:
    """Rows waiting for one stream table; :meth:`append` writes them out once ``flush_s`` seconds have passed."""

    def __init__(self, h5: h5py.File, name: str, flush_s: float):
        self._h5, self._dataset, self._flush_s = h5, h5[f"streams/{name}"], flush_s
        self._pending: list[np.ndarray] = []
        self._last = time.monotonic()

    @property
    def rows(self) -> int:
        """Rows written and waiting: the number the next row appended gets."""
        return self._dataset.shape[0] + sum(len(rows) for rows in self._pending)

    def append(self, rows: np.ndarray) -> None:
        self._pending.append(rows)
        if time.monotonic() - self._last >= self._flush_s:
            self.flush()

    def flush(self) -> None:
        self._last = time.monotonic()
        if not self._pending:
            return
        rows = np.concatenate(self._pending)
        self._pending = []
        n = self._dataset.shape[0]
        self._dataset.resize(n + len(rows), axis=0)
        self._dataset[n:] = rows
        self._h5.flush()
