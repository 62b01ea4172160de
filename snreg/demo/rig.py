"""The hardware-free rig of ``snreg-gui --demo``: simulated devices wired through the real code paths.

Why: the demo and the GUI tests must exercise what a phantom session runs (a frame source read and
tracked, an IMU on a serial port read by :class:`SerialImuReader` and fused, the camera-to-trocar
chain), only with rendered frames and a simulated IMU. The IMU simulator runs as its own process
(``snreg imu simulate``) on a pseudo-terminal, as a real device is outside the app: its work
does not compete with the GUI for the interpreter. The session file is not the rig's: whoever runs
it (the app, the headless demo) creates it.

``camera="still"``: the phantom of :mod:`snreg.demo.scene`; the IMU is held still as the endoscope lies in the patient
on the tilted table (``--still --attitude``), and the chain's reference is there
(:func:`~snreg.demo.phantom.still_demo_chain`), so the trocar frame is the camera frame shifted by the trocar-camera
distance along the shaft, which the tests use as ground truth, and gravity in it agrees with the SPECT's patient
position and the table's tilt. ``camera="surgery"``: :mod:`snreg.demo.surgery_scene`, the camera sliding and turning
between rests in the same patient; the simulator plays the same motion (``--motion``), holding its start
``IMU_HOLD_S`` after its stream starts (its fusion's still start) and writing the host-clock instant the motion starts
(``--epoch-file``); the rendered feed counts its frames from that instant (``epoch_ns``), so each frame meets the
orientation it was rendered at, however long the simulator process took to start. The IMU starts first (it is shown
streaming, not stale, while the scene is prepared), and the surgery tour is rendered as it plays: a process of its own
(:mod:`snreg.demo.render_process`, driven by a thread started with the rig) renders its distinct frames in tour order up
to :data:`RENDER_AHEAD_S` ahead of the play, the feed renders any frame not ready yet itself, and
:attr:`DemoRig.preparing` says how far rendering has come ("rendering the surgery tour, 40 of 145"), so the first frame
comes after the IMU's hold, not after the whole tour (~25 s of CPU, 10-30 s).

``hold_rests`` (the app's demo and the headless one, issue 35): the technician holds the probe on each node until it
is stored, as a real one does, however few frames a loaded computer processes: the feed's frames map to the tour's
through :class:`~snreg.demo.held_tour.HeldTour`, whose rests end on :meth:`DemoRig.release_rest` (the node stored) or
after a maximum; the surgery camera's IMU simulator is told each run of that clock over its standard input
(``--timeline-stdin``), so the camera and the IMU hold and move on together. A frame's ``index`` stays the feed's (it
counts wall-clock frames, skipped ones included); :meth:`DemoRig.tour_frame` gives the tour
frame (the scene's truth) at it.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from snreg.calibration.checkerboard import THESIS_BOARD
from snreg.camera import thesis_calibration
from snreg.chain import camera_to_trocar, reference_rotation, trocar_from_camera
from snreg.child_process import end_child
from snreg.demo.board_tour import board_feed
from snreg.demo.error_rig import INJECTED, INJECTED_MOVING, DemoErrors
from snreg.demo.errors import ErrorModel
from snreg.demo.held_tour import HeldTour
from snreg.demo.motion_timeline import Run
from snreg.demo.phantom import (TRUE_TILT_DEG, TRUE_TURN_DEG, endoscope_orientation, still_demo_chain,
                                 true_sources_lps, write_phantom_spect)
from snreg.demo.pivot_scene import PivotScene, SceneImu
from snreg.demo.render_process import TourRenderProcess
from snreg.demo.scene import PhantomScene, Schedule, phantom_tips
from snreg.demo.surgery_scene import SurgeryScene, surgery_demo_chain, surgery_tour
from snreg.demo.tissue_pivot import TissuePivotScene
from snreg.files import atomic_write
from snreg.geometry import euler_from_rotation
from snreg.imu.monitor import ImuMonitor
from snreg.probe import default_probe_model
from snreg.sources import CallableSource, FrameSource

DEMO_FPS = 30.0
CAMERAS = ("still", "surgery")
# The interactive demo's rests (``snreg-gui --demo``, the rig's default schedule): long enough for a person to see the
# readiness line turn green and press Store SN. The store window needs 60 fixes: 2 s of a full-rate feed, 4 s when the
# live feed processes every other frame on a loaded computer, which leaves 11 s of "ready". The headless demo and the
# tests pass their own, shorter schedules (nobody presses a key there).
INTERACTIVE_REST_S = 15.0
IMU_START_TIMEOUT_S = 60.0     # the simulator process starting on a heavily loaded machine
IMU_HOLD_S = 5.0               # the surgery tour starts this long after the IMU stream: the fusion's still start (its
                               # 3 s start-up, then 2 s at its normal gain to settle from level to the tilted patient's
                               # pose: 0.4 deg left after 3 s) before the camera first moves
RELEASE_LEAD_S = 1.0           # with held rests, the probe lifts this long after its node was stored: the stored node
                               # is seen on screen before it moves, and the IMU simulator is told the run in time
MAX_HOLD_S = 60.0              # with held rests and nobody storing, the tour moves on after this many seconds' worth of
                               # frames processed past a rest's end (more wall-clock time on a loaded computer)
RENDER_AHEAD_S = 10.0          # the surgery tour is rendered this far ahead of the play (a rest and the move after it)


def interactive_schedule(fps: float = DEMO_FPS) -> Schedule:
    """The rests of the demo a person drives (:data:`INTERACTIVE_REST_S` at ``fps``), either camera."""
    return Schedule(rest_frames=round(INTERACTIVE_REST_S * fps))


class DemoRig:
    """A :class:`~snreg.rig.protocols.Rig` of simulated devices: calibration, chain, simulated IMU;
    :meth:`frame_source` starts the IMU reader and builds the rendered feed; the wizards get a rendered
    checkerboard tour, and a pivot recording over a board and a turn over tissue, each with its own IMU.

    scale: the thesis 1920x1080 cameras at this fraction of their resolution (rendering speed).
    """

    simulated = True

    def __init__(self, *, scale: float = 0.5, schedule: Schedule | None = None, fps: float = DEMO_FPS, seed: int = 0,
                 errors: ErrorModel | None = None, camera: str = "still", hold_rests: bool = False,
                 release_lead_s: float = RELEASE_LEAD_S, max_hold_s: float = MAX_HOLD_S):
        """``errors``: an error model (:mod:`snreg.demo.errors`) the rig runs with, drawn under ``seed``
        (:class:`~snreg.demo.error_rig.DemoErrors`); None: nothing errs but the render's noise (the ideal model).
        ``camera``: "still" (the thesis' phantom) or "surgery" (the camera slides and turns between nodes).
        ``schedule``: the probe's rests and moves (default: :func:`interactive_schedule`, rests a person can press
        Store SN in). ``hold_rests``: the technician holds the probe on each node until it is stored
        (:meth:`release_rest`: the probe lifts ``release_lead_s`` later, before the rest's nominal end if the store
        came first) or, with nobody storing, after ``max_hold_s`` worth of frames processed past the rest's nominal end
        (:mod:`snreg.demo.held_tour`);
        else rests last their nominal frames of wall-clock time, stored or not."""
        if camera not in CAMERAS:
            raise ValueError(f"the demo camera is 'still' or 'surgery', not {camera!r}")
        self.camera = camera
        full = thesis_calibration()
        self.cameras = full.scaled(scale)                      # the simulated cameras as they truly are
        self.probe = default_probe_model()
        injected = INJECTED_MOVING if self.moving_camera else INJECTED
        self.errors = (DemoErrors(errors, self.probe, full, scale=scale, seed=seed, injected=injected)
                       if errors is not None else None)
        # what tracking uses (a calibration wizard replaces it): under an error model, one solved from noisy corners
        self.calibration = self.cameras if self.errors is None or self.errors.calibration is None else self.errors.calibration
        # the set-up as it happened, the chain as it truly is (referenced where the endoscope starts), and what
        # tracking uses (the trocar wizard replaces it)
        self.setup_deg = (TRUE_TILT_DEG, TRUE_TURN_DEG) if self.errors is None else self.errors.setup_deg
        if self.moving_camera:
            self.true_chain = surgery_demo_chain(self.setup_deg)
        else:
            self.true_chain = still_demo_chain(endoscope_orientation(self.setup_deg))
        self.chain = self.true_chain
        if schedule is None:
            schedule = interactive_schedule(fps)
        self.schedule, self.fps, self.seed = schedule, fps, seed
        self.scene: PhantomScene | SurgeryScene | None = None
        self._folder = tempfile.TemporaryDirectory(prefix="snreg-demo-imu-")
        self._link = Path(self._folder.name) / "imu"
        self._epoch_ns: int | None = None
        self._epoch_file = Path(self._folder.name) / "epoch"
        self.hold_rests = bool(hold_rests)
        self._hold_options = dict(held=self.hold_rests, lead_frames=math.ceil(release_lead_s * fps),
                                  max_hold_frames=round(max_hold_s * fps))
        self._tour: HeldTour | None = None      # the tour's clock: the surgery camera's one for the rig's life (the
        self._feed_index = 0                    # IMU plays it), the still one's per feed; the newest feed frame
        if self.moving_camera:                  # its process starts while the tour renders
            motion = Path(self._folder.name) / "motion.json"
            tour = surgery_tour(self.schedule, self.true_chain)
            with atomic_write(motion) as temporary:
                temporary.write_text(json.dumps(tour.motion_profile(self.true_chain, self.fps).to_dict()))
            held = ("--timeline-stdin",) if self.hold_rests else ()
            self._launch_imu("--motion", str(motion), "--hold", str(IMU_HOLD_S), "--epoch-file", str(self._epoch_file),
                             *held)
            self._tour = HeldTour([(first, self.schedule.rest_frames) for first in tour.rest_starts], tour.cycle,
                                  self.fps, send=self._send_run if self.hold_rests else None, **self._hold_options)
        else:
            attitude = ",".join(f"{v:.6f}" for v in euler_from_rotation(self._start_orientation()))
            self._launch_imu("--still", f"--attitude={attitude}")
        self.imu = ImuMonitor(str(self._link))
        self._played = 0                        # the tour frame the feed asked for last (the renderer keeps ahead of it)
        self._renderer: threading.Thread | None = None
        self._stop_rendering, self._scene_ready = threading.Event(), threading.Event()
        if self.moving_camera:                  # the tour starts rendering now: the app's start-up is time gained
            self._renderer = threading.Thread(target=self._render_ahead, name="demo-tour-renderer", daemon=True)
            self._renderer.start()

    @property
    def moving_camera(self) -> bool:
        """Whether the camera slides and turns, so acquisition follows its insertion: the surgery camera's. Not the
        still phantom's, whose tissue plane follows the probe's depth (tracking would read that as slides)."""
        return self.camera == "surgery"

    @property
    def description(self) -> str:
        scene = "rendered surgery, the camera sliding and turning" if self.moving_camera else "rendered phantom"
        return f"demo: {scene}, simulated IMU"

    def frame_source(self) -> FrameSource:
        """The rendered stereo feed; call it in the worker thread (the IMU process starting and the still scene
        pre-rendering take seconds; the surgery tour renders beside the feed as it plays). Raises OSError when the
        IMU simulator did not come up."""
        self._start_imu()                       # the IMU streams while the scene is prepared
        if self.moving_camera:                  # its renderer builds it and renders it as it plays
            self._scene_ready.wait()
            if self.scene is None:
                raise OSError("the surgery demo's scene could not be built; see the log")
        elif self.scene is None:                # rendered once: a restart after a calibration replays the same tour
            scene = PhantomScene(self.cameras, self.probe, self.schedule, seed=self.seed, **self._scene_options())
            scene.prerender()
            self.scene = scene
        if self.moving_camera and self._epoch_ns is None:
            self._epoch_ns = self._wait_for_epoch()
        # a camera (docs/design.md, Conventions): frames stamped at grab on the host clock of the IMU samples and stored nodes, and
        # skipped when tracking falls behind, while the scene goes on at its own pace (the surgery tour's counted
        # from the IMU motion's start, so a restart goes on where the tour is)
        if not self.moving_camera:              # a restart replays the still tour from its start
            rest = self.schedule.rest_frames + self.schedule.move_frames
            self._tour = HeldTour([(n * rest, self.schedule.rest_frames) for n in range(len(self.scene.node_poses))],
                                  self.scene.cycle, self.fps, **self._hold_options)
        name = "Demo surgery" if self.moving_camera else "Demo phantom"
        return CallableSource(self._play, self.fps, live=True, name=name, epoch_ns=self._epoch_ns)

    @property
    def preparing(self) -> str:
        """What the rig is still preparing, in words ("rendering the surgery tour, 40 of 145"); "" when nothing."""
        if not self.moving_camera:
            return ""
        scene = self.scene
        if scene is None:
            return "preparing the surgery tour"
        done, total = scene.rendered, scene.distinct_frames
        return f"rendering the surgery tour, {done} of {total}" if done < total else ""

    def _play(self, index: int):
        """The feed's frame ``index``: the tour's frame then (the surgery tour's rendered now when the renderer ahead
        has not yet)."""
        self._feed_index = index
        shown = self._tour.shown_frame(index)
        self._played = shown
        return self.scene.render(shown)

    def tour_frame(self, feed_index: int) -> int:
        """The tour frame (the scene's index: its truth) the feed showed at its frame ``feed_index``."""
        return self._tour.tour_frame(feed_index)

    def release_rest(self, feed_index: int | None = None) -> bool:
        """A node was stored on feed frame ``feed_index`` (default: the newest shown): with ``hold_rests`` the probe
        lifts off that rest's node ``release_lead_s`` from now (the surgery camera and its IMU move on together).
        False when nothing changes (rests not held, the probe moving, or that rest's end set already). Thread-safe:
        call it from the thread that stored."""
        if self._tour is None:
            return False
        now = self._feed_index
        if self._epoch_ns is not None:          # the surgery feed's clock: the feed may be behind it
            now = max(now, int((time.perf_counter_ns() - self._epoch_ns) * self.fps // 1e9))
        return self._tour.release(now if feed_index is None else feed_index, now)

    def _send_run(self, run: Run) -> None:
        """Hand a run of the tour's timeline to the IMU simulator (its standard input)."""
        try:
            self._simulator.stdin.write(run.line())
            self._simulator.stdin.flush()
        except (OSError, ValueError):           # the simulator ended: the IMU shows stale, and the demo says so
            pass

    def _scene_options(self) -> dict:
        """The error model's noise, blur and pointing for the rendered scene (none under the ideal model)."""
        return {} if self.errors is None else {"noise_sigma": self.errors.noise_sigma, "blur_sigma_px": self.errors.blur_px,
                                               "tip_offsets_mm": self.errors.tip_offsets_mm}

    def _render_ahead(self) -> None:
        """The renderer beside the feed, from the rig's start: builds the surgery scene, then has the tour's distinct
        frames rendered in order, up to :data:`RENDER_AHEAD_S` ahead of the frame played last, until all are rendered
        or the rig closes: in a process of its own (:class:`~snreg.demo.render_process.TourRenderProcess`, so its
        Python never holds the app's GIL), in this thread when that process cannot start or ends early."""
        args = (self.cameras, self.probe, self.schedule)
        kwargs = dict(chain=self.true_chain, fps=self.fps, seed=self.seed, **self._scene_options())
        try:
            scene = SurgeryScene(*args, **kwargs)
            self.scene = scene
        finally:
            self._scene_ready.set()
        within = int(RENDER_AHEAD_S * self.fps)
        try:
            process = TourRenderProcess(scene, args, kwargs, within)
        except OSError:
            process = None
        try:
            while not self._stop_rendering.is_set() and scene.rendered < scene.distinct_frames:
                if process is not None and not process.ended:
                    process.follow(self._played)
                    self._stop_rendering.wait(0.05)
                elif not scene.render_next(self._played, within):
                    self._stop_rendering.wait(0.05)    # all near frames ready: wait for the play to move on
        finally:
            if process is not None:
                process.close()

    def nodes_trocar(self) -> np.ndarray:
        """(4, 3) mm: where the phantom's nodes are in the trocar frame (the truth a stored node is measured by)."""
        return camera_to_trocar(self.true_chain, self._start_orientation(), phantom_tips(self.probe))

    def true_trocar_from_camera(self, index: int) -> np.ndarray:
        """(4, 4) the camera's true pose at tour frame ``index`` (:meth:`tour_frame` of a feed frame): the surgery
        tour's there, the still camera's at the start orientation; call it once :meth:`frame_source` has built the
        scene."""
        if self.moving_camera:
            return self.scene.trocar_from_camera(index)
        return trocar_from_camera(self.true_chain, self._start_orientation())

    def phantom_sources_lps(self) -> np.ndarray:
        """(4, 3) LPS mm: where the phantom's sources were when the SPECT was made (the truth the demo's SPECT images)."""
        shift = 0.0 if self.errors is None else self.errors.scan_shift_mm
        return true_sources_lps(phantom_tips(self.probe), self.true_chain, setup_deg=self.setup_deg,
                                scan_shift_mm=shift, earth_from_imu=self._start_orientation())

    def _start_orientation(self) -> np.ndarray:
        """(3, 3) the IMU's true orientation where the nodes are defined from: the chain's reference pose (the camera
        along the trocar axis), where the still camera stays and the surgery tour starts."""
        chain = self.true_chain
        return (chain.trocar_from_earth[:3, :3].T @ reference_rotation(chain.shaft_camera)
                @ chain.imu_from_camera[:3, :3].T)

    def write_phantom_spect(self, path) -> Path:
        """Write the phantom's SPECT (NM DICOM) at ``path`` with the error model's voxels, resolution and counts."""
        return write_phantom_spect(self.phantom_sources_lps(), path, self.seed,
                                   **({} if self.errors is None else self.errors.spect))

    def board_source(self) -> FrameSource:
        """A rendered checkerboard tour seen by the simulated cameras as they truly are (the calibration to find)."""
        return board_feed(self.cameras)

    def pivot_source(self) -> tuple[Callable[[], FrameSource], SceneImu]:
        """A rendered pivot recording and the IMU that moves with it (frame and orientation belong together)."""
        scene = PivotScene(self.cameras, THESIS_BOARD)
        return scene.frame_source, SceneImu(scene)

    def tissue_source(self) -> tuple[Callable[[], FrameSource], SceneImu]:
        """A rendered turn about the trocar over tissue and the IMU that moves with it (0.2 degrees of noise)."""
        scene = TissuePivotScene(self.cameras, seed=self.seed)
        return scene.frame_source, scene.imu

    def _launch_imu(self, *motion: str) -> None:
        """Start the IMU simulator process (``motion``: its options saying what the sensor does) on the rig's link."""
        self._simulator = subprocess.Popen(
            [sys.executable, "-m", "snreg.cli", "imu", "simulate", *motion, "--seed", str(self.seed),
             "--port-link", str(self._link), "--parent", str(os.getpid())],
            stdin=subprocess.PIPE if "--timeline-stdin" in motion else None, text=True,
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def _wait_for_epoch(self) -> int:
        """The instant (host clock, ns) the simulator's motion starts: it writes it once the reader opened its port."""
        deadline = time.monotonic() + IMU_START_TIMEOUT_S
        while not self._epoch_file.exists():
            if self._simulator.poll() is not None or time.monotonic() > deadline:
                raise OSError(f"the IMU simulator did not start its motion (exit status {self._simulator.poll()}); "
                              "try 'snreg imu simulate --motion FILE' to see why")
            time.sleep(0.01)
        return int(self._epoch_file.read_text())

    def _start_imu(self) -> None:
        if self.imu.started:
            return
        deadline = time.monotonic() + IMU_START_TIMEOUT_S
        while not self._link.exists():
            if self._simulator.poll() is not None or time.monotonic() > deadline:
                raise OSError(f"the IMU simulator did not start (exit status {self._simulator.poll()}); "
                              "try 'snreg imu simulate --still' to see why")
            time.sleep(0.02)
        self.imu.start()

    def close(self) -> None:
        """Stop the tour's renderer, the IMU reader and its simulator process; call after the worker has stopped."""
        self._stop_rendering.set()
        if self._renderer is not None:
            self._renderer.join()
        self.imu.stop()
        self._simulator.terminate()
        end_child(self._simulator, 5.0)
        self._folder.cleanup()
