"""Summaries and node export of session files (the work behind ``snreg session info|export``)."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import h5py
import numpy as np

from snreg.camera import save_calibration
from snreg.files import atomic_write
from snreg.landmarks import LANDMARK
from snreg.nodes import NodeFile
from snreg.session import Session
from snreg.session.integrity import verify
from snreg.session.journal import journal_path, read_journal
from snreg.session.pose_streams import tracked_rows
from snreg.session.schema import STREAM_DTYPES, SessionError, covariance_json


def session_info(path: str | Path) -> dict:
    """JSON-ready summary: case id, creation time, versions, counts of nodes and stream rows, each intraop node's id,
    label, the insertion it was mapped with (``trocar_camera_mm``, null when untracked) and its own error's covariance
    (``cov_trocar_mm2``, 3x3 mm^2 in the trocar frame, null when unknown), the stored landmarks apart (``landmarks``,
    the same fields, id = name; ``intraop_landmarks`` and ``preop_landmarks`` their counts), the camera stream's
    tracked and lost pairs, what gives the preop nodes' down (``preop_down``: patient position, table tilt, whether it
    was entered, and ``source`` in words; null when unknown), calibration, registrations, events by kind (e.g.
    ``store_refused``), the recorded videos;
    ``damaged`` also when a dataset fails its checksum or digest (``damage`` names them; the videos' SHA-256 is left
    to ``snreg session verify``)."""
    with Session.open(path) as session:                 # refuses what is not a session, in one sentence
        checked = verify(path, videos=False)
        preop = session.preop_nodes()
        camera = session.stream("camera")
        tracked = int(tracked_rows(camera[()] if isinstance(camera, h5py.Dataset) else camera).sum())
        return {"case_id": session.case_id, "created_utc": session.header.get("created_utc", ""),
                "format_version": session.header.get("format_version"),
                "snreg_version": session.header.get("snreg_version", ""),
                "intraop_nodes": len(session.intraop_records()), "preop_nodes": 0 if preop is None else len(preop),
                "intraop_landmarks": len(session.intraop_records(LANDMARK)),
                "preop_landmarks": len(session.preop_landmarks()),
                "preop_down": None if session.preop_down() is None else {**session.preop_down().to_json(),
                                                                           "source": session.preop_down().source},
                "streams": {name: int(session.stream(name).shape[0]) for name in STREAM_DTYPES},
                "nodes": [_point_info(node) for node in session.intraop_records()],
                "landmarks": [_point_info(node) for node in session.intraop_records(LANDMARK)],
                "camera": {"tracked": tracked, "lost": int(len(camera)) - tracked},
                "calibration": sorted(session.calibration()),
                "registrations": [{"n": r.n, "method": r.result.method, "rms_mm": r.result.rms_mm, "final": r.final}
                                  for r in session.registrations()],
                "final_registration": session.final_registration(),
                "events": dict(Counter(event["kind"] for event in session.events())),
                "videos": [{key: video[key] for key in ("side", "path", "frames", "codec")} for video in checked.videos],
                "damaged": session.damaged or not checked.ok, "damage": [d.to_json() for d in checked.damaged],
                "journal_damaged_lines": read_journal(journal_path(path)).damaged,
                "journal": session.has_journal, "problems": list(session.problems)}


def _point_info(node) -> dict:
    return {"id": node.id, "label": node.label,
            "trocar_camera_mm": float(node.trocar_camera_mm) if np.isfinite(node.trocar_camera_mm) else None,
            "cov_trocar_mm2": covariance_json(node.cov_trocar_mm2)}


def export_calibration(path: str | Path, out: str | Path) -> None:
    """Write the stereo calibration a session used as a calibration file (docs/design.md, Contracts "Calibration file")."""
    with Session.open(path) as session:
        stereo = session.calibration().get("stereo")
    if stereo is None:
        raise SessionError(f"{path}: the session holds no stereo calibration to export")
    save_calibration(stereo, out)


def export_nodes(path: str | Path, fmt: str, out: str | Path) -> NodeFile:
    """Write the intraop nodes and, apart, the stored landmarks (trocar frame, mm) as node CSV (landmarks as rows of
    ``kind`` landmark) or 3D Slicer markups (landmarks in their own point list); returns what was written."""
    with Session.open(path) as session:
        points = NodeFile(session.intraop_nodes(), session.intraop_landmarks())
    text = points.to_csv() if fmt == "csv" else json.dumps(points.to_slicer(), indent=2)
    with atomic_write(out) as temporary:
        temporary.write_text(text, encoding="utf-8")
    return points
