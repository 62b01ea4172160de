"""What the registration panel's workers do: register and store, keep the preop set in the session, write the exports.

Why: registration, the session's fsynced writes and figure rendering can each take longer than a frame, so
they run off the GUI thread (docs/design.md, Habits). The inputs travel as one frozen :class:`RunRequest` and come back
with the result as a :class:`RunRecord`, so a result always stays with the node sets that produced it even
if the technician changes them while it runs. Each side's nodes are weighed by their own covariances when every node
of that side has one (a stored node's from the tracker and chain, a hot spot's from the segmentation), as
``snreg register`` does; :func:`weighing_text` says which. No widgets here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from snreg.nodes import NodeSet, write_nodes
from snreg.preop.gravity import PreopDown
from snreg.registration import RegistrationResult, register
from snreg.registration.naming import shown_preop_ids
from snreg.registration.report import mapped_preop, save_report_png, write_pairs_csv
from snreg.registration.report_meta import ReportContext, sidecar_path
from snreg.registration.wording import labels_given, used_inputs
from snreg.session import Session, SessionError
from snreg.workflow.chain_change import mixed_calibration_note
from snreg.workflow.registration_start import GravityStart

# kind: (name, file dialog filter, suffix added when the chosen name ends in none of the accepted ones)
EXPORTS = {"pairs": ("pairing CSV", "CSV (*.csv)", (".csv",)),
           "slicer": ("Slicer markups", "3D Slicer markups (*.mrk.json)", (".mrk.json", ".json")),
           "report": ("report PNG", "PNG image (*.png)", (".png",))}


@dataclass(frozen=True)
class RunRequest:
    """One registration as chosen in the panel; ``session`` set only when the result is to be stored.

    ``preop_landmarks``/``intraop_landmarks``: the landmarks to pair by name (ids = names; None: none), in the app the
    preop landmarks read with the preop nodes (stored with them) and the session's
    (:meth:`~snreg.session.Session.intraop_landmarks`); ``landmark_sd_mm`` their own error, sd per axis.
    ``gravity``: start from the two downs (:func:`~snreg.workflow.registration_start.session_gravity`), searching every
    heading, instead of ``initial`` (the typed angles, then ignored); ``preop_down``: what gives the preop nodes' down
    (the SPECT's patient position and the table's tilt), stored with them."""

    preop: NodeSet
    intraop: NodeSet
    method: str
    use_labels: bool
    initial: np.ndarray
    max_rotation_deg: float
    max_translation_mm: float
    session: Session | None = None
    preop_landmarks: NodeSet | None = None
    intraop_landmarks: NodeSet | None = None
    landmark_sd_mm: float = 2.0
    gravity: GravityStart | None = None
    preop_down: PreopDown | None = None

    @property
    def start(self) -> str:
        """The start in words: ``"start: gravity, table tilt 30 deg head down (default), heading searched"``."""
        return self.gravity.words if self.gravity is not None else "start: the initial alignment entered"


@dataclass(frozen=True)
class RunRecord:
    """A result with the node sets it pairs (and the landmarks it was given, None for none), and what happened to it
    in the session (one sentence, or ""); ``weighing``: how the nodes were weighed (:func:`weighing_text`; "" when not
    known, e.g. a registration read from a session)."""

    preop: NodeSet
    intraop: NodeSet
    result: RegistrationResult
    note: str = ""
    stored: bool = False
    final_n: int | None = None          # the session's registration number when this is the one marked final
    preop_landmarks: NodeSet | None = None
    intraop_landmarks: NodeSet | None = None
    weighing: str = ""
    start: str = ""                     # where the search started, in words ("" for a stored result)
    used: str = ""                      # labels, landmarks, covariances used, in words ("" for a stored result)


def weighing_text(preop: NodeSet, intraop: NodeSet, method: str) -> str:
    """One sentence: whose own covariances weighed the nodes in a registration of these sets, and why a side's did not
    (every node of a side needs one); icp, cpd and chamfer fit without them, their confidence and bounds use them."""
    intraop_used, preop_used = intraop.known_cov is not None, preop.known_cov is not None
    if intraop_used and preop_used:
        text = "each stored node and each SPECT hot spot weighed by its own error (covariance)"
    elif intraop_used:
        text = ("each stored node weighed by its own error (covariance); the SPECT hot spots alike (the preop nodes "
                f"{'carry none' if preop.cov is None else 'lack some'})")
    elif preop_used:
        text = ("each SPECT hot spot weighed by its own error (covariance); the stored nodes alike ("
                f"{'none carries one' if intraop.cov is None else 'some lack one'}: stored before they were computed, "
                "or from a node file)")
    else:
        return "Every node weighed alike: neither side's nodes all carry their own error (covariance)."
    if method != "global" and (intraop_used or preop_used):
        text += f"; {method} fits without them, its confidence and expected errors use them"
    return text[0].upper() + text[1:] + "."


def used_text(request: RunRequest, result: RegistrationResult) -> str:
    """What a run used, in words (:class:`~snreg.registration.wording.UsedInputs`), saying how to use what it did
    not."""
    preop, intraop = request.preop, request.intraop
    given = labels_given(preop.labels) and labels_given(intraop.labels)
    labels_why = ("tick 'use labels' to use them" if given else
                  "the " + " and the ".join(side for side, nodes in (("SPECT nodes", preop), ("stored nodes", intraop))
                                            if not labels_given(nodes.labels)) + " carry none")
    missing = [side for side, nodes in (("stored", intraop), ("SPECT", preop)) if nodes.known_cov is None]
    return used_inputs(result, labels=request.use_labels and given, intraop_cov=intraop.known_cov is not None,
                       preop_cov=preop.known_cov is not None, labels_why=labels_why,
                       landmarks_why="none named on both the CT and in surgery",
                       cov_why=f"the {' and '.join(missing)} nodes do not all carry one").text()


def save_preop(session: Session, nodes: NodeSet, landmarks: NodeSet | None = None,
               down: PreopDown | None = None) -> str:
    """Store ``nodes`` (and the preop ``landmarks`` read with them, and what gives their ``down``) as the session's
    preop set unless it holds exactly them already (worker thread: an fsynced write). Returns "" when stored or already
    there, else one sentence saying why it was not."""
    marks = landmarks if landmarks is not None and len(landmarks) else None
    if not session.writable or (_same_set(session.preop_nodes(), nodes) and _same_marks(session, marks)
                                and _same_down(session.preop_down(), down)):
        return ""
    try:
        session.set_preop_nodes(nodes, marks, down=down)
    except (SessionError, OSError) as err:
        return f"The preop nodes could not be saved in the session ({getattr(err, 'strerror', None) or err})."
    return ""


def _same_marks(session: Session, marks: NodeSet | None) -> bool:
    stored = session.preop_landmarks() if session.preop_nodes() is not None else None
    if marks is None:
        return stored is None or not len(stored)
    return _same_set(stored, marks)


def _same_down(a: PreopDown | None, b: PreopDown | None) -> bool:
    return a == b


def _same_set(a: NodeSet | None, b: NodeSet) -> bool:
    """Same ids, labels, positions and covariances (none on both sides, or equal)."""
    if a is None or a.ids != b.ids or a.labels != b.labels or not np.array_equal(a.xyz, b.xyz):
        return False
    return (a.cov is None) == (b.cov is None) and (a.cov is None or np.array_equal(a.cov, b.cov, equal_nan=True))


def final_record(session: Session) -> RunRecord | None:
    """The registration marked final in ``session`` with the node sets it paired (the exports use it); None when
    none is marked. ValueError, in one sentence, when its nodes are no longer the session's (preop set replaced,
    intraop node undone): its result can then not be put beside them."""
    n = session.final_registration()
    if n is None:
        return None
    stored = next(r for r in session.registrations() if r.n == n)
    preop, intraop = session.preop_nodes(), session.intraop_nodes()
    lost = stored.preop_ids is None or stored.intraop_ids is None or preop is None \
        or stored.preop_ids != preop.ids or not set(stored.intraop_ids) <= set(intraop.ids)
    if lost:
        raise ValueError(f"registration {n} is marked final but the session no longer holds the node sets it paired "
                         "(preop set replaced or a node undone); mark another one final, or unmark it")
    keep = [intraop.ids.index(i) for i in stored.intraop_ids]
    paired = NodeSet(stored.intraop_ids, [intraop.labels[k] for k in keep], intraop.xyz[keep],
                     None if intraop.counts is None else intraop.counts[keep], frame=intraop.frame)
    return RunRecord(preop, paired, stored.result, f"Registration {n}, marked final.", True, n,
                     session.preop_landmarks(), session.intraop_landmarks())


def run_registration(request: RunRequest) -> RunRecord:
    """Register (worker thread); store the preop set and the result when the request carries a session. When the
    session's nodes registered were mapped with different calibrations, the note says so first (issue 12: never
    mix two frames silently)."""
    record = _run(request)
    if request.session is None:
        return record
    stored = {node.id: node for node in request.session.intraop_records(kind=None)}
    used = request.intraop.ids + ([] if request.intraop_landmarks is None else request.intraop_landmarks.ids)
    mixed = mixed_calibration_note([stored[i] for i in used if i in stored])
    return replace(record, note=f"{mixed} {record.note}".strip()) if mixed else record


def _run(request: RunRequest) -> RunRecord:
    preop, intraop = request.preop, request.intraop
    labels = (preop.labels, intraop.labels) if request.use_labels else (None, None)
    marks = [None if m is None or not len(m) else m for m in (request.preop_landmarks, request.intraop_landmarks)]
    gravity = request.gravity
    result = register(preop.xyz, intraop.xyz, method=request.method, preop_labels=labels[0],
                      intraop_labels=labels[1], initial=request.initial if gravity is None else None,
                      max_rotation_deg=request.max_rotation_deg, max_translation_mm=request.max_translation_mm,
                      intraop_cov=intraop.known_cov, preop_cov=preop.known_cov,
                      preop_landmarks=marks[0], intraop_landmarks=marks[1], landmark_sd_mm=request.landmark_sd_mm,
                      down=None if gravity is None else gravity.down)
    record = RunRecord(preop, intraop, result, preop_landmarks=request.preop_landmarks,
                       intraop_landmarks=request.intraop_landmarks,
                       weighing=weighing_text(preop, intraop, request.method), start=request.start,
                       used=used_text(request, result))
    if request.session is None:
        return record
    if not request.session.writable:
        return replace(record, note="Review session: the result is shown but not stored (the file is open for reading).")
    try:
        problem = save_preop(request.session, preop, request.preop_landmarks,
                             request.preop_down)   # the registration names its preop ids
        if problem:
            return replace(record, note=f"{problem} The result is shown but not stored; export it instead.")
        n = request.session.add_registration(result, preop.ids, intraop.ids)
    except (SessionError, OSError) as err:
        return replace(record, note=f"The result could not be stored in the session "
                                    f"({getattr(err, 'strerror', None) or err}); export it instead.")
    return replace(record, note=f"Stored in the session as registration {n}.", stored=True)


def report_context(session: Session | None) -> ReportContext:
    """What the PNG report says about the session a registration comes from: case id, file, and the stereo
    calibration and chain stored in it now (their quality figures, date and versions); empty without a session."""
    if session is None:
        return ReportContext()
    stored = session.calibration()
    stereo, chain = stored.get("stereo"), stored.get("chain")
    stereo_version, chain_version = session.calibration_versions()
    return ReportContext(case_id=session.case_id, session_path=str(session.path),
                         stereo_rms_px=None if stereo is None else float(stereo.rms_reprojection_px),
                         stereo_views=None if stereo is None else int(stereo.n_views or 0),
                         stereo_created_utc="" if stereo is None else str(stereo.created_utc),
                         stereo_version=stereo_version,
                         trocar_camera_mm=None if chain is None else chain.trocar_camera_mm,
                         chain_version=chain_version)


def export_file(kind: str, path: str, record: RunRecord, context: ReportContext | None = None) -> Path:
    """Write one export of ``record`` (worker thread): ``pairs`` CSV, ``slicer`` markups (the preop nodes mapped into
    the intraop frame, and the preop landmarks so mapped in a point list of their own) or ``report`` PNG (with its
    sidecar JSON, both carrying ``context``: :func:`report_context`).

    Written beside the target under a hidden name and then renamed, so a reader (3D Slicer, a script watching
    the folder) never sees a half-written file and a failed export leaves no file."""
    suffixes = EXPORTS[kind][2]
    path = Path(path if str(path).lower().endswith(suffixes) else f"{path}{suffixes[0]}")
    partial = path.with_name(f".~{path.name}")            # same ending: the writers choose the format by it
    final = "" if record.final_n is None else f"registration {record.final_n} of the session, marked final"
    try:
        if kind == "pairs":
            write_pairs_csv(partial, record.preop, record.intraop, record.result)
            if final:
                partial.write_text(f"# registration: {final}\n" + partial.read_text(encoding="utf-8"), encoding="utf-8")
        elif kind == "slicer":
            mapped = mapped_preop(record.preop, record.result)
            marks = None if record.preop_landmarks is None else mapped_preop(record.preop_landmarks, record.result)
            write_nodes(replace(mapped, comments=mapped.comments + [final] if final else mapped.comments), partial,
                        landmarks=marks)
        else:
            shown = replace(record.preop, ids=shown_preop_ids(record.preop.ids, record.intraop.ids))   # "P:SN4"
            context = replace(context or ReportContext(), final_registration=record.final_n, used=record.used)
            save_report_png(partial, shown, record.intraop, record.result, title=final.capitalize(), context=context)
            os.replace(sidecar_path(partial), sidecar_path(path))
        os.replace(partial, path)
    except OSError as err:
        partial.unlink(missing_ok=True)
        if kind == "report":
            sidecar_path(partial).unlink(missing_ok=True)
        raise ValueError(f"{path}: cannot write the {EXPORTS[kind][0]} ({err.strerror or err}); "
                         "choose another folder") from None
    return path

