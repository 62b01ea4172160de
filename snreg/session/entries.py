"""What each journal entry (and each part read back from the HDF5 file) must hold, checked field by field.

Why: a journal line's checksum proves only that the line was written whole, not that the program that wrote it (an
older or newer snreg, a tool, a hand edit) gave every field its right type. A node without a label, a position that
is a string or a registration number that is text would otherwise stop every reader of the session with a
traceback, and the good nodes in the lines around it with it. Each entry is checked here once; one that fails is
reported (``journal line 12 (node): lacks 'label'``) and left out, and everything else is read.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from snreg.chain import ChainCalibration
from snreg.landmarks import KINDS as POINT_KINDS
from snreg.landmarks import LANDMARK, landmark_name
from snreg.nodes import NodeSet
from snreg.preop.gravity import PreopDown
from snreg.session.schema import FORMAT, StoredRegistration, stereo_from_dict

__all__ = ["EntryError", "check_entry", "checked_entries", "check_node", "KINDS"]

_INT64 = 2 ** 63


class EntryError(ValueError):
    """One entry that cannot be used; the message names the field and what is wrong with it."""


def _text(value, empty: bool = True) -> str:
    if not isinstance(value, str):
        raise EntryError(f"is {_kind(value)}, not text")
    if not empty and not value.strip():
        raise EntryError("is empty")
    return value


def _integer(value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != value or \
            (isinstance(value, float) and not value.is_integer()):
        raise EntryError(f"is {_kind(value)}, not a whole number")
    if abs(value) >= _INT64:
        raise EntryError("is too large")
    return int(value)


def _number(value, finite: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise EntryError(f"is {_kind(value)}, not a number")
    number = float(value) if abs(value) < 1e308 or isinstance(value, float) else math.inf
    if finite and not math.isfinite(number):
        raise EntryError("is not a finite number")
    return number


def _array(shape, finite: bool = False):
    """A checker for a nested list of numbers of ``shape`` (-1: any length)."""
    def check(value) -> list:
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise EntryError(f"is not {'x'.join('n' if n < 0 else str(n) for n in shape)} numbers") from None
        if array.ndim != len(shape) or any(n >= 0 and n != m for n, m in zip(shape, array.shape)):
            raise EntryError(f"has shape {array.shape}, not {tuple('n' if n < 0 else n for n in shape)}")
        if finite and not np.all(np.isfinite(array)):
            raise EntryError("holds NaN or infinite values")
        return array.tolist()
    return check


def _texts(value) -> list:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise EntryError("is not a list of text")
    return value


def _hex(value) -> str:
    text = _text(value)
    try:
        bytes.fromhex(text)
    except ValueError:
        raise EntryError("is not hexadecimal bytes") from None
    return text


def _point_kind(value) -> str:
    if value not in POINT_KINDS:
        raise EntryError(f"is {value!r}, not one of {', '.join(POINT_KINDS)}")
    return value


def _names_mm(value) -> dict:
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):
        raise EntryError("is not a record of landmark names")
    return {k: _number(v) for k, v in value.items()}


def _landmark_results(value) -> dict:
    return _fields(value, {"residual_mm": _names_mm, "leave_one_out_mm": _names_mm, "suspect": _texts})


def _optional(check: Callable):
    def optional(value):
        return None if value is None else check(value)
    optional.optional = True
    return optional


_NODE = {"id": lambda v: _text(v, empty=False), "label": _text, "time_ns": _integer,
         "xyz_trocar": _array((3,), finite=True), "xyz_camera": _array((3,)), "spread_mm": _number,
         "n_frames": _integer, "counts": _number, "left_jpeg": _hex, "right_jpeg": _hex,
         "earth_from_imu": _optional(_array((3, 3))), "stereo_version": _optional(_text),
         "chain_version": _optional(_text), "trocar_camera_mm": _optional(_number),
         "cov_trocar_mm2": _optional(_array((3, 3))), "kind": _optional(_point_kind)}
_CHANGE = {"id": lambda v: _text(v, empty=False), "xyz_trocar": _array((3,), finite=True), "xyz_camera": _array((3,)),
           "stereo_version": _text, "chain_version": _text, "trocar_camera_mm": _optional(_number),
           "cov_trocar_mm2": _optional(_array((3, 3)))}
_REGISTRATION = {"n": _integer, "method": _text, "rms_mm": _number, "pairing_rule": _text,
                 "transform": _array((4, 4), finite=True), "pairing": _array((-1,), finite=True),
                 "distances_mm": _array((-1,)), "confidence": _array((-1,)), "preop_ids": _optional(_texts),
                 "intraop_ids": _optional(_texts), "initial": _optional(_array((4, 4), finite=True)),
                 "target_error_mm": _optional(_array((-1,))), "missing": _optional(_array((-1,))),
                 "leave_one_out_mm": _optional(_array((-1,))), "final": _optional(lambda v: bool(v)),
                 "landmarks": _optional(_landmark_results)}
_DROPPED_WHEN_NULL = {"earth_from_imu", "stereo_version", "chain_version",   # null there means "not recorded"
                      "trocar_camera_mm", "cov_trocar_mm2", "kind", "landmarks"}


def _preop_down(value) -> dict:
    try:
        return PreopDown.from_json(value).to_json()
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise EntryError(f"is not a patient position with a table tilt ({_short(err)})") from None


_PREOP = {"ids": _texts, "labels": _texts, "xyz": _array((-1, 3), finite=True), "counts": _optional(_array((-1,))),
          "frame": _text, "cov": _optional(_array((-1, 3, 3))), "down": _optional(_preop_down)}
_PREOP_LANDMARKS = {"ids": _texts, "labels": _texts, "xyz": _array((-1, 3), finite=True)}


def _fields(data, spec: dict, extra: bool = True) -> dict:
    """``data`` with every field of ``spec`` checked (a missing optional field stays missing)."""
    if not isinstance(data, dict):
        raise EntryError(f"is {_kind(data)}, not a record")
    out = dict(data) if extra else {}
    for key, check in spec.items():
        if key not in data or (data[key] is None and getattr(check, "optional", False) and key in _DROPPED_WHEN_NULL):
            if getattr(check, "optional", False):
                out.pop(key, None)                  # the reader's default stands for a missing optional field
                continue
            raise EntryError(f"lacks {key!r}")
        try:
            out[key] = check(data[key])
        except EntryError as err:
            raise EntryError(f"{key!r} {err}") from None
    return out


def check_node(data) -> dict:
    """A node in the journal's JSON form (:meth:`IntraopNode.to_json`), checked field by field: it builds an
    :class:`IntraopNode` (a landmark's id a landmark name)."""
    data = _fields(data, _NODE)
    if data.get("kind") == LANDMARK:
        try:
            landmark_name(data["id"])
        except ValueError as err:
            raise EntryError(f"'id' {err}") from None
    return data


def _event(data) -> dict:
    data = _fields(data, {"kind": lambda v: _text(v, empty=False), "n": _optional(_integer)})
    return _reexpression(data) if data["kind"] == "nodes_reexpressed" else data


def _reexpression(data) -> dict:
    data = _fields(data, {"kind": _text, "n": _optional(_integer)})
    changes = data.get("nodes")
    if not isinstance(changes, list):
        raise EntryError("'nodes' is not a list of node changes")
    data["nodes"] = [_fields(change, _CHANGE) for change in changes]
    return data


def _final(data) -> dict:
    if not isinstance(data, dict) or "n" not in data:
        raise EntryError("lacks 'n'")
    return {"n": None if data["n"] is None else _integer(data["n"])}


def _calibration(data) -> dict:
    data = _fields(data, {"kind": _text})
    if data["kind"] not in ("stereo", "chain") or not isinstance(data.get("data"), dict):
        raise EntryError(f"is not a stereo or chain calibration (kind {data['kind']!r})")
    try:
        if data["kind"] == "stereo":
            stereo_from_dict(data["data"])
        else:
            ChainCalibration.from_dict(data["data"])
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as err:
        raise EntryError(f"does not make a {data['kind']} calibration ({_short(err)})") from None
    return data


def _registration(data) -> dict:
    data = _fields(data, _REGISTRATION)
    if data["n"] < 0:
        raise EntryError("'n' is negative")
    try:
        StoredRegistration.from_json(data)
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as err:
        raise EntryError(f"does not make a registration ({_short(err)})") from None
    return data


def _preop(data) -> dict:
    data = _fields(data, _PREOP)
    data.setdefault("counts", None)                  # not given: no counts (the readers expect the key)
    data.setdefault("cov", None)                     # not given (older files): no covariances
    data.setdefault("down", None)                    # not given (older files, node files from elsewhere): unknown
    marks = data.get("landmarks")
    try:
        NodeSet(data["ids"], data["labels"], data["xyz"], data["counts"], frame=data["frame"], cov=data["cov"])
        if marks is not None:
            marks = data["landmarks"] = _fields(marks, _PREOP_LANDMARKS)
            NodeSet(marks["ids"], marks["labels"], marks["xyz"])
            for name in marks["ids"]:
                landmark_name(name)
    except EntryError as err:
        raise EntryError(f"'landmarks' {err}") from None
    except ValueError as err:
        raise EntryError(f"does not make a node set ({_short(err)})") from None
    data.setdefault("landmarks", None)               # not given (before format 5): no preop landmarks
    return data


def _file_names(value) -> list:
    names = _texts(value)
    if len(names) != 2 or any(not name or "/" in name or "\\" in name or name in (".", "..") for name in names):
        raise EntryError("is not two file names beside the session")
    return names


_VIDEO = {"n": _integer, "files": _file_names, "first_row": _integer, "fps": lambda v: _number(v, finite=True),
          "width": _integer, "height": _integer, "closed": _optional(lambda v: bool(v)),
          "frames": _optional(_array((2,), finite=True)), "size": _optional(_array((2,), finite=True)),
          "sha256": _optional(_texts), "dropped": _optional(_integer), "codec": _optional(_text),
          "container": _optional(_text), "stopped": _optional(_text)}


def _video(data) -> dict:
    data = _fields(data, _VIDEO)
    if data["n"] < 0 or data["first_row"] < 0:
        raise EntryError("'n' or 'first_row' is negative")
    for key in ("frames", "size"):
        if key in data:
            data[key] = [int(v) for v in data[key]]
    return data


def _header(data) -> dict:
    data = _fields(data, {"format": _text})
    if data["format"] != FORMAT:
        raise EntryError(f"is not a snreg session header (format {data['format']!r})")
    for key in ("case_id", "created_utc", "snreg_version"):
        if not isinstance(data.get(key, ""), str):
            raise EntryError(f"{key!r} is {_kind(data[key])}, not text")
    if "format_version" in data:
        data["format_version"] = _integer(data["format_version"])
    return data


KINDS: dict[str, Callable[[object], dict]] = {
    "session": _header, "node": check_node, "node_removed": lambda d: _fields(d, {"id": _text}),
    "event": _event, "nodes_reexpressed": _reexpression, "calibration": _calibration, "preop": _preop,
    "registration": _registration, "final": _final, "video": _video,
}


def check_entry(kind: str, data):
    """``data`` of a ``kind`` entry, checked; :class:`EntryError` names what is wrong."""
    check = KINDS.get(kind)
    if check is None:
        raise EntryError(f"is of a kind this snreg does not know ({kind!r})")
    try:
        return check(data)
    except RecursionError:
        raise EntryError("is nested too deeply") from None


def checked_entries(entries: list, lines: list[int] | None = None) -> tuple[list, list[str]]:
    """The entries that pass :func:`check_entry`, in order, and one sentence per entry left out (its journal line)."""
    kept, problems = [], []
    for k, (kind, data) in enumerate(entries):
        try:
            kept.append((kind, check_entry(kind, data)))
        except EntryError as err:
            where = f"journal line {lines[k]}" if lines and k < len(lines) else f"journal entry {k + 1}"
            problems.append(f"{where} ({kind}) {err}; left out")
    return kept, problems


def _kind(value) -> str:
    if value is None:
        return "missing (null)"
    return {bool: "true/false", int: "a number", float: "a number", str: "text", list: "a list",
            dict: "a record"}.get(type(value), type(value).__name__)


def _short(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= 120 else text[:117] + "..."
