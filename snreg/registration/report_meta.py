"""What a PNG report says about itself: case, date, session file, calibration, method, RMS, counts, version.

Why: a report found in a folder weeks later must say which case, session and calibration it came from and which
software made it, both on the page (the header lines) and for tools: the same facts are written into the PNG's
text chunks (key :data:`REPORT_KEY`, one JSON object) and into a sidecar JSON of the same stem, so a script or a
test reads them back without parsing pixels (:func:`read_report_metadata`).

>>> context = ReportContext(case_id="phantom-01", session_path="/data/phantom-01.h5", stereo_rms_px=0.31)
>>> meta = report_metadata(result, rows, missing, context)     # JSON-ready dict
>>> header_lines(meta)                                          # the lines printed at the top of the report
>>> read_report_metadata("report.png") == meta                  # from the PNG text chunk
"""

from __future__ import annotations

import datetime
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from snreg import __version__
from snreg.registration import RegistrationResult
from snreg.registration.wording import rule_words

__all__ = ["ReportContext", "report_metadata", "header_lines", "png_text_chunks", "read_report_metadata",
           "sidecar_path", "REPORT_KEY", "REPORT_FORMAT"]

REPORT_KEY = "snreg-report"                   # the PNG text chunk holding the metadata as JSON
REPORT_FORMAT = "snreg-registration-report"


def _now_utc() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


@dataclass(frozen=True)
class ReportContext:
    """Where a registration comes from, as far as the caller knows it (a session's header and calibration);
    defaults say "not known". ``date_utc`` is when the report is made."""

    case_id: str = ""
    session_path: str = ""
    stereo_rms_px: float | None = None
    stereo_views: int | None = None
    stereo_created_utc: str = ""
    stereo_version: str = ""
    trocar_camera_mm: float | None = None
    chain_version: str = ""
    final_registration: int | None = None     # the session's registration number when it is the one marked final
    used: str = ""                 # what the registration used, in words (wording.UsedInputs.text); "" unknown
    date_utc: str = field(default_factory=_now_utc)

    def calibration_line(self) -> str:
        """One line: stereo RMS, views, when made and its version; the chain's distance and version."""
        if self.stereo_rms_px is None:
            stereo = "stereo calibration not known"
        else:
            rms = "RMS not recorded" if math.isnan(self.stereo_rms_px) else f"RMS {self.stereo_rms_px:.2f} px"
            views = f", {self.stereo_views} views" if self.stereo_views else ""
            made = f", made {self.stereo_created_utc}" if self.stereo_created_utc else ""
            stereo = f"stereo {rms}{views}{made} (version {self.stereo_version or '?'})"
        chain = ("chain not known" if self.trocar_camera_mm is None else
                 f"chain trocar-camera {self.trocar_camera_mm:.1f} mm (version {self.chain_version or '?'})")
        return f"{stereo}; {chain}"


def report_metadata(result: RegistrationResult, rows, missing, context: ReportContext | None = None,
                    warnings=()) -> dict:
    """The report's facts as a JSON-ready dict: ``rows`` are the result's pair rows, ``missing`` its missing
    preop nodes (:mod:`snreg.registration.report`), ``warnings`` the sentences about nodes to check."""
    context = context or ReportContext()
    session = Path(context.session_path).name if context.session_path else ""
    return {"format": REPORT_FORMAT, "snreg_version": __version__, "date_utc": context.date_utc,
            "case_id": context.case_id, "session_file": session, "session_path": context.session_path,
            "calibration": context.calibration_line(),
            "stereo_rms_px": context.stereo_rms_px, "stereo_views": context.stereo_views,
            "stereo_created_utc": context.stereo_created_utc, "stereo_version": context.stereo_version,
            "trocar_camera_mm": context.trocar_camera_mm, "chain_version": context.chain_version,
            "final_registration": context.final_registration, "used": context.used,
            "method": result.method, "pairing_rule": result.pairing_rule, "rms_mm": round(float(result.rms_mm), 4),
            "n_intraop": len(rows), "n_paired": sum(row.paired for row in rows),
            "n_extra": sum(not row.paired for row in rows), "missing_preop_ids": [m.preop_id for m in missing],
            "warnings": list(warnings),
            "intraop_from_preop": np.round(np.asarray(result.transform, dtype=float), 6).tolist()}


def header_lines(meta: dict) -> list[str]:
    """The report's header: case and date, session and version, calibration, the result in numbers."""
    missing = meta["missing_preop_ids"]
    return [f"case {meta['case_id'] or '(no case id)'}    report made {meta['date_utc']} (UTC)    "
            f"snreg {meta['snreg_version']}",
            f"session {meta['session_file'] or '(no session file)'}",
            f"calibration: {meta['calibration']}",
            f"method {meta['method']} ({rule_words(meta['pairing_rule'])}): RMS {meta['rms_mm']:.2f} mm, "
            f"{meta['n_paired']} of {meta['n_intraop']} intraop nodes paired, {meta['n_extra']} extra, "
            f"{len(missing)} preop node{'' if len(missing) == 1 else 's'} missing"
            + (f" ({', '.join(missing)})" if missing else ""),
            meta.get("used") or "what the registration used (labels, landmarks, covariances) is not recorded"]


def png_text_chunks(meta: dict) -> dict[str, str]:
    """The PNG text chunks for matplotlib's ``savefig(metadata=...)``: the standard keys and :data:`REPORT_KEY`."""
    return {"Title": f"snreg registration report, case {meta['case_id'] or '(none)'}",
            "Software": f"snreg {meta['snreg_version']}", "Creation Time": meta["date_utc"],
            "Description": "\n".join(header_lines(meta)), REPORT_KEY: json.dumps(meta, sort_keys=True)}


def sidecar_path(png_path) -> Path:
    """The sidecar JSON beside a report: same folder and stem, ``.json``."""
    return Path(png_path).with_suffix(".json")


def read_report_metadata(path) -> dict:
    """The metadata of a report: from the PNG's :data:`REPORT_KEY` text chunk (a ``.png``) or a sidecar ``.json``;
    ValueError when the file carries none."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        meta = json.loads(path.read_text(encoding="utf-8"))
    else:
        from PIL import Image  # matplotlib's own PNG dependency

        with Image.open(path) as image:
            text = image.info.get(REPORT_KEY)
        if text is None:
            raise ValueError(f"{path}: not an snreg report (no {REPORT_KEY} text chunk)")
        meta = json.loads(text)
    if meta.get("format") != REPORT_FORMAT:
        raise ValueError(f"{path}: not an snreg report")
    return meta
