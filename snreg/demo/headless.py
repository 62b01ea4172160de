"""``snreg demo --headless``: the phantom experiment end to end with no window and no hardware.

Why: proof that the whole chain works on the code the app runs: rendered stereo feeds read from a
frame source and tracked, a simulated IMU on a pseudo-terminal read through pyserial and fused, the
camera-to-trocar chain, nodes auto-stored into a crash-safe session (the probe held still on each
source; the "technician" types the label written on the phantom), the phantom's SPECT written as NM
DICOM, read back and segmented, and the preop nodes registered to the stored ones with ``global``
from gravity (:mod:`snreg.workflow.registration_start`: the SPECT's patient position and the table tilt the team
enters, snreg's default; the IMU through the chain's reference), with no angle typed (:mod:`snreg.demo.phantom`).

With a live link (:class:`snreg.workflow.live_link.LiveLink`) the run feeds it as the app does: every processed
frame, every stored node, the preop nodes once segmented and the registration; the seconds the loop spends in those
calls are counted, since a link that blocked would cost frames there.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from snreg.demo.phantom import PHANTOM_LABELS
from snreg.demo.rig import DemoRig
from snreg.demo.scene import NODE_CENTRES_MM, Schedule, phantom_tips
from snreg.preop.gravity import volume_down
from snreg.preop.segment import segment_nodes
from snreg.preop.volume import load_volume
from snreg.registration import RegistrationResult, register
from snreg.registration.naming import pairs_line
from snreg.registration.report import pair_table
from snreg.session import Session
from snreg.workflow.acquisition import Acquisition, ImuReading
from snreg.workflow.registration_start import session_gravity

N_NODES = len(NODE_CENTRES_MM)
_IMU_WAIT_S = 5.0


class DemoError(RuntimeError):
    """The demo could not finish; the message says where it stopped."""


@dataclass(frozen=True)
class HeadlessResult:
    """The run: session and SPECT files, the stored and segmented nodes, the registration and its truth check."""

    session_path: Path
    spect_path: Path
    result: RegistrationResult
    intraop_ids: list[str]
    intraop_labels: list[str]
    intraop_xyz: np.ndarray
    preop_ids: list[str]
    pairing_correct: bool
    frames: int
    recording_s: float = float("nan")
    link_s: float = 0.0
    link_calls: int = 0
    intraop_cov: np.ndarray | None = None         # (M, 3, 3) each stored node's covariance, mm^2, trocar frame

    def to_json(self) -> dict:
        """``{"rms_mm", "pairing", "nodes", ...}``: pairing is the preop index per stored node (-1 extra), as in the API."""
        rows = pair_table(self.result, self.preop_ids, self.intraop_ids, intraop_labels=self.intraop_labels)
        nodes = [{"id": row.intraop_id, "label": row.intraop_label,
                  "xyz_trocar": [round(float(v), 3) for v in self.intraop_xyz[k]],
                  "preop": row.preop_id if row.paired else None, "distance_mm": round(row.distance_mm, 3),
                  "confidence": round(row.confidence, 4),
                  "cov_trocar_mm2": None if self.intraop_cov is None else np.round(self.intraop_cov[k], 4).tolist()}
                 for k, row in enumerate(rows)]
        return {"rms_mm": round(float(self.result.rms_mm), 3), "pairing": [int(v) for v in self.result.pairing],
                "nodes": nodes, "method": self.result.method, "pairing_correct": self.pairing_correct,
                "frames": self.frames, "recording_s": round(self.recording_s, 3), "session": str(self.session_path),
                "spect": str(self.spect_path)}


def spect_path_for(session_path: str | Path) -> Path:
    """Where the demo writes the phantom's SPECT: beside the session, ``<name>-spect.dcm``."""
    session_path = Path(session_path)
    return session_path.with_name(session_path.stem + "-spect.dcm")


class _TimedLink:
    """Calls into the live link (none without one), with the wall time the calling thread spends in them."""

    def __init__(self, link):
        self.link, self.seconds, self.calls = link, 0.0, 0

    def __call__(self, method: str, *args) -> None:
        if self.link is None:
            return
        started = time.perf_counter()
        getattr(self.link, method)(*args)
        self.seconds += time.perf_counter() - started
        self.calls += 1


def run_headless(session_path: str | Path, *, seed: int = 0, fixes_per_node: int = 60, scale: float = 0.5,
                 link=None, errors=None, video: bool = True) -> HeadlessResult:
    """Record the four phantom nodes into a new session at ``session_path``, then register the phantom's SPECT.

    ``link``: a :class:`~snreg.workflow.live_link.LiveLink` to feed, or None; ``errors``: the
    :class:`~snreg.demo.errors.ErrorModel` the rig runs with (None: today's ideal demo); ``video``: record both feeds
    beside the session."""
    session_path = Path(session_path)
    # the feed is live (frames skipped while tracking lags), so each rest lasts twice the frames a node needs
    rig = DemoRig(scale=scale, schedule=Schedule(rest_frames=2 * fixes_per_node + 30), seed=seed, errors=errors)
    feed = _TimedLink(link)
    try:
        with Session.create(session_path, case_id="phantom-demo") as session:
            session.set_calibration(stereo=rig.calibration, chain=rig.chain)
            started = time.perf_counter()
            frames = _record(rig, session, fixes_per_node, feed, video)
            recording_s = time.perf_counter() - started
            tips = phantom_tips(rig.probe)
            sources = rig.phantom_sources_lps()
            spect = rig.write_phantom_spect(spect_path_for(session_path))
            volume = load_volume(spect)
            preop = segment_nodes(volume, n_nodes=N_NODES).nodes
            session.set_preop_nodes(preop, down=volume_down(volume))
            feed("set_preop_nodes", preop)
            intraop = session.intraop_nodes()
            result = register(preop.xyz, intraop.xyz, method="global", preop_labels=preop.labels,
                              intraop_labels=intraop.labels, down=session_gravity(session).down, seed=seed)
            session.add_registration(result, preop.ids, intraop.ids)
            feed("set_registration", result, pairs_line(preop, intraop, result))
    finally:
        rig.close()
    truth = _true_pairing(preop.xyz, sources, tips, session.intraop_records())
    return HeadlessResult(session_path, spect, result, intraop.ids, intraop.labels, intraop.xyz, preop.ids,
                          bool(np.array_equal(result.pairing, truth)), frames, recording_s, feed.seconds, feed.calls,
                          intraop.cov)


def _record(rig: DemoRig, session: Session, fixes_per_node: int, feed: _TimedLink, video: bool = True) -> int:
    """Run the tour until every node is auto-stored, feeding the live link; returns the frames read (the live feed
    skips some)."""
    source = rig.frame_source()
    if not _wait_for_imu(rig):
        raise DemoError(f"the simulated IMU sent nothing for {_IMU_WAIT_S:.0f} s ({rig.imu.snapshot().problem})")
    acquisition = Acquisition(rig.calibration, rig.probe, rig.chain, session, fixes_per_node=fixes_per_node,
                              video_fps=rig.fps if video else None)
    limit, read, tail = 2 * rig.schedule.cycle, 0, 0
    with source:
        for frame in source:
            read += 1
            outcome = acquisition.process(frame, ImuReading.at_frame(rig.imu, frame))
            feed("show_frame", outcome)
            if outcome.auto_store_due:
                node = rig.scene.resting_node(frame.index)
                label = PHANTOM_LABELS[node] if node is not None else ""
                feed("add_node", acquisition.store(session.next_node_id(), label, left_jpeg=frame.left,
                                                   right_jpeg=frame.right))
            if len(session.intraop_records()) == N_NODES:
                tail += 1                            # a second more on record: a replay meets the last rest whole
                if tail > _tail_frames(rig):
                    return read
            if frame.index >= limit:
                break
    raise DemoError(f"only {len(session.intraop_records())} of {N_NODES} nodes were stored in {limit} frames "
                    f"({source.problem or 'the probe was never tracked still long enough'})")


def _tail_frames(rig: DemoRig) -> int:
    """Frames recorded after the last node is stored: one second."""
    return round(rig.fps)


def _wait_for_imu(rig: DemoRig) -> bool:
    deadline = time.monotonic() + _IMU_WAIT_S
    while time.monotonic() < deadline:
        if rig.imu.snapshot().samples > 0:
            return True
        time.sleep(0.02)
    return False


def _true_pairing(preop_xyz, sources, tips, records) -> np.ndarray:
    """The preop index each stored node should pair with: the segmented node nearest its source, the source being
    the one whose rendered tip (camera frame) is nearest the node."""
    preop_of_source = np.argmin(np.linalg.norm(sources[:, None, :] - preop_xyz[None, :, :], axis=2), axis=1)
    source_of_node = [int(np.argmin(np.linalg.norm(tips - node.xyz_camera, axis=1))) for node in records]
    return preop_of_source[source_of_node]
