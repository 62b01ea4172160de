"""``snreg demo --headless``: the phantom experiment end to end with no window and no hardware.

Why: proof that the whole chain works on the code the app runs: rendered stereo feeds read from a
frame source and tracked, a simulated IMU on a pseudo-terminal read through pyserial and fused, the
camera-to-trocar chain, nodes auto-stored into a crash-safe session (the probe held still on each
source; the "technician" types the label written on the phantom), the phantom's SPECT written as NM
DICOM, read back and segmented, and the preop nodes registered to the stored ones with ``global``
from gravity (:mod:`snreg.workflow.registration_start`: the SPECT's patient position and the table tilt the team
enters, snreg's default; the IMU through the chain's reference), with no angle typed (:mod:`snreg.demo.phantom`).
The technician holds the probe on each node until it is stored (issue 35: :class:`~snreg.demo.held_tour.HeldTour`),
however few frames a loaded computer processes, and lifts it once stored or after :data:`_GIVE_UP_WINDOWS` store
windows of processed frames without a store (a node that never holds still: the failure then says why).

With a live link (:class:`snreg.workflow.live_link.LiveLink`) the run feeds it as the app does: every processed
frame, every stored node, the preop nodes once segmented and the registration; the seconds the loop spends in those
calls are counted, since a link that blocked would cost frames there.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from snreg import geometry
from snreg.demo.navigation_log import NavigationLog, hot_spot_truth
from snreg.demo.phantom import PHANTOM_LABELS, hot_spot_of_sources
from snreg.demo.phantom_preop import N_NODES, spect_path_for, stations_path_for, write_phantom_preop
from snreg.demo.rest_log import RestLog
from snreg.demo.rig import DEMO_FPS, DemoRig
from snreg.demo.scene import Schedule
from snreg.demo.staging import publish, staging_folder
from snreg.odometry import InsertionTracker
from snreg.preop.gravity import volume_down
from snreg.nodes import NodeFile
from snreg.registration import RegistrationResult
from snreg.registration.naming import pairs_line
from snreg.registration.report import missing_nodes, pair_table
from snreg.registration.wording import confidence_value, labels_given, used_inputs
from snreg.session import Session
from snreg.tracking.stereo import StereoTracker
from snreg.workflow.acquisition import STILL_SPREAD_MM, Acquisition, ImuReading
from snreg.workflow.navigation import trocar_from_camera_at
from snreg.workflow.node_registration import node_covariances, register_nodes
from snreg.workflow.registration_start import session_gravity

MIN_NODES = 3              # stored nodes a registration needs (the phantom has no landmarks)
# The demo registers as ``snreg register SESSION.h5`` does (:func:`~snreg.workflow.node_registration.register_nodes`:
# each node's covariance, the landmarks) with the labels typed on the phantom, which that command uses when asked:
# these options repeat it, confidences and all.
REPEAT_OPTIONS = "--labels"
_IMU_WAIT_S = 5.0
_TOURS = 3                 # of the nodes at most, before giving up (a node that never holds still)
_GIVE_UP_WINDOWS = 3       # the technician lifts a probe not stored after this many store windows of frames processed
_RELEASE_LEAD_S = 0.3      # the probe lifts this long after its node is stored (the surgery IMU is told in time)


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
    truth_trocar: np.ndarray              # (M, 3) where each stored node's phantom node really is, trocar frame, mm
    camera: str = "still"
    camera_tracking: bool = False
    recording_s: float = float("nan")
    link_s: float = 0.0
    link_calls: int = 0
    intraop_cov: np.ndarray | None = None         # (M, 3, 3) each stored node's covariance, mm^2, trocar frame
    weighed: tuple[bool, bool] = (False, False)   # whether the (intraop, preop) nodes' covariances were given
    navigation: tuple = ()                        # the hot spots not found yet per frame, against the truth

    def used(self):
        """What the demo's registration used (:class:`~snreg.registration.wording.UsedInputs`): the labels typed on the
        phantom and each side's covariances when all its nodes carry one, as ``snreg register`` with
        :data:`REPEAT_OPTIONS`."""
        missing = [side for side, used in zip(("stored", "SPECT"), self.weighed) if not used]
        return used_inputs(self.result, labels=labels_given(self.intraop_labels), intraop_cov=self.weighed[0],
                           preop_cov=self.weighed[1], labels_why="none typed", landmarks_why="the phantom has none",
                           cov_why=f"the {' and '.join(missing)} nodes do not all carry one")

    def to_json(self) -> dict:
        """``{"rms_mm", "pairing", "nodes", ...}``: pairing is the preop index per stored node (-1 extra), as in the
        API; each node with ``truth_trocar``, the simulator's truth."""
        rows = pair_table(self.result, self.preop_ids, self.intraop_ids, intraop_labels=self.intraop_labels)
        nodes = [{"id": row.intraop_id, "label": row.intraop_label,
                  "xyz_trocar": [round(float(v), 3) for v in self.intraop_xyz[k]],
                  "truth_trocar": [round(float(v), 3) for v in self.truth_trocar[k]],
                  "preop": row.preop_id if row.paired else None, "distance_mm": round(row.distance_mm, 3),
                  "confidence": confidence_value(row.confidence),
                  "cov_trocar_mm2": None if self.intraop_cov is None else np.round(self.intraop_cov[k], 4).tolist()}
                 for k, row in enumerate(rows)]
        return {"rms_mm": round(float(self.result.rms_mm), 3), "pairing": [int(v) for v in self.result.pairing],
                "nodes": nodes, "method": self.result.method, "pairing_correct": self.pairing_correct,
                "used": self.used().as_json(), "repeat": f"snreg register {self.session_path} {REPEAT_OPTIONS}",
                "camera": self.camera, "camera_tracking": self.camera_tracking, "frames": self.frames,
                "recording_s": round(self.recording_s, 3), "session": str(self.session_path),
                "spect": str(self.spect_path), "navigation": list(self.navigation)}


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
                 link=None, errors=None, video: bool = True, camera: str = "still",
                 camera_tracking: bool = True, fps: float = DEMO_FPS) -> HeadlessResult:
    """Record the four phantom nodes into a new session at ``session_path``, then register the phantom's SPECT.

    ``link``: a :class:`~snreg.workflow.live_link.LiveLink` to feed, or None; ``errors``: the
    :class:`~snreg.demo.errors.ErrorModel` the rig runs with (None: today's ideal demo); ``video``: record both feeds
    beside the session; ``camera``: "still" or "surgery" (:class:`~snreg.demo.rig.DemoRig`); ``camera_tracking``:
    follow the insertion of a camera that moves (off: every node is mapped at the trocar calibration's distance, to
    compare); ``fps``: the feed's pace (the tour's frames last longer at a lower one: a loaded computer then
    processes more of them, for measurements; the command line keeps the demo's own).

    The run records into a hidden folder beside ``session_path`` (:mod:`snreg.demo.staging`) and its files (session,
    journal, videos, SPECT) move there only when it completes: a run that fails leaves ``session_path`` free for the
    retry, its recording kept in that folder (the :class:`DemoError` names it)."""
    target = Path(session_path)
    folder = staging_folder(target)
    try:
        run = _run(folder / target.name, seed=seed, fixes_per_node=fixes_per_node, scale=scale, link=link,
                   errors=errors, video=video, camera=camera, camera_tracking=camera_tracking, fps=fps)
    except DemoError as err:
        raise DemoError(f"{err}; the recording so far is kept in {folder} to look at (delete it when done), and "
                        f"{target.name} was not written, so the same command can run again") from None
    publish(folder, target, replaceable=(spect_path_for(target).name, stations_path_for(target).name))
    return replace(run, session_path=target, spect_path=spect_path_for(target))


def rest_frames_for(fixes_per_node: int) -> int:
    """The headless demo's rests, in frames, before the technician holds on (:class:`~snreg.demo.held_tour.HeldTour`):
    the frames a node needs at the full rate and a second more (either camera). A rest ends when its node is stored,
    so it is shorter when the computer keeps up, and held longer when the live feed skips frames (a loaded computer):
    its length never decides whether the window fills."""
    return fixes_per_node + 30


def _run(session_path: Path, *, seed: int, fixes_per_node: int, scale: float, link, errors, video: bool, camera: str,
         camera_tracking: bool, fps: float = DEMO_FPS) -> HeadlessResult:
    """:func:`run_headless` into ``session_path`` as it is (the staging folder's)."""
    schedule = Schedule(rest_frames=rest_frames_for(fixes_per_node))
    rig = DemoRig(scale=scale, schedule=schedule, seed=seed, errors=errors, camera=camera, fps=fps, hold_rests=True,
                  release_lead_s=_RELEASE_LEAD_S)
    feed = _TimedLink(link)
    try:
        with Session.create(session_path, case_id="phantom-demo") as session:
            session.set_calibration(stereo=rig.calibration, chain=rig.chain)
            sources = rig.phantom_sources_lps()         # the SPECT is there before surgery: registered after each store
            written = write_phantom_preop(rig, session_path)      # the SPECT and its report of stations
            spect, preop = written.spect_path, written.nodes
            session.set_preop_nodes(preop, down=volume_down(written.volume))
            feed("set_preop_nodes", preop)
            started = time.perf_counter()
            tracking = camera_tracking and rig.moving_camera
            navigation = NavigationLog(preop, hot_spot_truth(preop.xyz, sources, rig.nodes_trocar()), None, None,
                                       rig.calibration.image_size)
            frames, stored_at = _record(rig, session, fixes_per_node, feed, video, tracking,
                                        lambda: _register(session, preop), navigation)
            recording_s = time.perf_counter() - started
            intraop = session.intraop_nodes()
            weighed = node_covariances(preop, intraop)
            result = _register(session, preop)
            session.add_registration(result, preop.ids, intraop.ids)
            feed("set_registration", result, pairs_line(preop, intraop, result))
            feed("set_missing", missing_nodes(preop, result))
    finally:
        rig.close()
    truth = hot_spot_of_sources(preop.xyz, sources)[stored_at]
    return HeadlessResult(session_path, spect, result, intraop.ids, intraop.labels, intraop.xyz, preop.ids,
                          bool(np.array_equal(result.pairing, truth)), frames, rig.nodes_trocar()[stored_at], camera,
                          tracking, recording_s, feed.seconds, feed.calls, intraop.cov,
                          tuple(weighed[side] is not None for side in ("intraop", "preop")), tuple(navigation.entries))


def _registered_or_none(register_now) -> RegistrationResult | None:
    """The registration after a store, or None when the nodes stored so far do not register yet (too few pairs by
    their sides, no fit within the bounds): the feeds then draw no hot spot, as the app's would, and the tour goes
    on."""
    try:
        return register_now()
    except ValueError:                  # NoFitError, TooFewPairsError: the next store may answer
        return None


def _register(session: Session, preop) -> RegistrationResult:
    """The demo's registration of the nodes stored in ``session`` now, as ``snreg register SESSION.h5 --labels`` does
    (:func:`~snreg.workflow.node_registration.register_nodes`: each side's covariances, the landmarks, the labels typed,
    from gravity); the one after each store is the one the feeds draw from, as the app's registration after a store."""
    return register_nodes(NodeFile(preop, session.preop_landmarks()),
                          NodeFile(session.intraop_nodes(), session.intraop_landmarks()), labels=True,
                          down=session_gravity(session).down)


def _record(rig: DemoRig, session: Session, fixes_per_node: int, feed: _TimedLink, video: bool = True,
            tracking: bool = False, register_now=None, navigation: NavigationLog | None = None) -> tuple[int, list[int]]:
    """Run the tour until every node is auto-stored, feeding the live link; returns the frames read (the live feed
    skips some) and, per stored node, the phantom node the probe rested on. ``tracking``: follow the insertion.
    ``register_now``: the registration of the nodes stored now, run after each store once there are
    :data:`MIN_NODES` (inline, as the app's worker would: about 50 ms), its hot spots not found yet logged per frame
    into ``navigation`` (:class:`~snreg.demo.navigation_log.NavigationLog`) against the truth."""
    source = rig.frame_source()
    if not _wait_for_imu(rig):
        raise DemoError(f"the simulated IMU sent nothing for {_IMU_WAIT_S:.0f} s ({rig.imu.snapshot().problem})")
    insertion = InsertionTracker(rig.calibration, rig.chain, probe=rig.probe) if tracking else None
    acquisition = Acquisition(rig.calibration, rig.probe, rig.chain, session, fixes_per_node=fixes_per_node,
                              video_fps=rig.fps if video else None, insertion=insertion)
    if navigation is not None:
        navigation.project = acquisition.tracker.project
        navigation.true_project = StereoTracker(rig.cameras, rig.probe).project
    first_ns = None
    limit, read, tail, stored_at, rests, ended = _TOURS * rig.scene.cycle, 0, 0, [], RestLog(), ""
    tour, at_rest, shown = 0, 0, 0             # the tour frame; frames processed on this rest; feed frames shown
    with source:
        for frame in source:
            read += 1
            shown, tour = frame.index + 1, rig.tour_frame(frame.index)
            reading = ImuReading.at_frame(rig.imu, frame)
            outcome = acquisition.process(frame, reading)
            feed("show_frame", outcome)
            first_ns = frame.t_left_ns if first_ns is None else first_ns
            if navigation is not None:
                pose = trocar_from_camera_at(acquisition.chain, reading.earth_from_imu, outcome.insertion)
                estimated = geometry.invert(pose)
                navigation.frame(frame.index, (frame.t_left_ns - first_ns) * 1e-9, estimated,
                                 geometry.invert(rig.true_trocar_from_camera(tour)), outcome.tip_trocar,
                                 set(stored_at))
            node = rig.scene.resting_node(tour)
            due = outcome.auto_store_due and node is not None
            if due:
                feed("add_node", acquisition.store(session.next_node_id(), PHANTOM_LABELS[node], left_jpeg=frame.left,
                                                   right_jpeg=frame.right))
                stored_at.append(node)
                if register_now is not None and navigation is not None and len(stored_at) >= MIN_NODES:
                    navigation.registered(_registered_or_none(register_now))
                    feed("set_missing", list(navigation.state.targets))
            at_rest = 0 if node is None else at_rest + 1
            if due or at_rest == _GIVE_UP_WINDOWS * fixes_per_node:      # stored, or never still: the probe lifts
                rig.release_rest(frame.index)
            rests.add(node, outcome, stored=due, window=fixes_per_node)
            if len(session.intraop_records()) == N_NODES:
                tail += 1                            # a second more on record: a replay meets the last rest whole
                if tail > _tail_frames(rig):
                    return read, stored_at
            if tour >= limit:
                break
        else:                                        # the feed ended before the tours did: its reason, while it has one
            ended = source.problem or "the frame source ended early"
    why = rests.why_missing(set(stored_at), PHANTOM_LABELS, fixes_per_node=fixes_per_node, still_mm=STILL_SPREAD_MM)
    raise DemoError(f"only {len(stored_at)} of {N_NODES} nodes were stored in {_TOURS} tour{'s' * (_TOURS > 1)} of "
                    f"the nodes ({read} of {shown} frames processed): " + "; ".join(p for p in (ended, why) if p))


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

