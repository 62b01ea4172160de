"""The hardware-free rig of ``snreg-gui --demo``: simulated devices wired through the real code paths.

Why: the demo and the GUI tests must exercise what a phantom session runs (a frame source read and
tracked, an IMU on a serial port read by :class:`SerialImuReader` and fused, the camera-to-trocar
chain), only with rendered frames and a simulated IMU. The IMU simulator runs as its own process
(``snreg imu simulate --still``) on a pseudo-terminal, as a real device is outside the app: its work
does not compete with the GUI for the interpreter. The session file is not the rig's: whoever runs
it (the app, the headless demo) creates it.
The IMU is held still as the endoscope lies in the patient on the tilted table (``--still --attitude``), and the
chain's reference is there (:func:`~snreg.demo.phantom.still_demo_chain`), so the trocar frame is the camera frame
shifted by the trocar-camera distance along the shaft, which the tests use as ground truth, and gravity in it agrees
with the SPECT's patient position and the table's tilt.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from snreg.calibration.checkerboard import THESIS_BOARD
from snreg.camera import thesis_calibration
from snreg.demo.board_tour import board_feed
from snreg.demo.pivot_scene import PivotScene, SceneImu
from snreg.demo.tissue_pivot import TissuePivotScene
from snreg.demo.error_rig import DemoErrors
from snreg.demo.errors import ErrorModel
from snreg.demo.phantom import (TRUE_TILT_DEG, TRUE_TURN_DEG, endoscope_orientation, still_demo_chain,
                                 true_sources_lps, write_phantom_spect)
from snreg.demo.scene import PhantomScene, Schedule, phantom_tips
from snreg.geometry import euler_from_rotation
from snreg.imu.monitor import ImuMonitor
from snreg.probe import default_probe_model
from snreg.sources import CallableSource, FrameSource

DEMO_FPS = 30.0
IMU_START_TIMEOUT_S = 60.0     # the simulator process starting on a heavily loaded machine


class DemoRig:
    """A :class:`~snreg.rig.protocols.Rig` of simulated devices: calibration, chain, simulated IMU;
    :meth:`frame_source` starts the IMU reader and builds the rendered feed; the wizards get a rendered
    checkerboard tour, and a pivot recording over a board and a turn over tissue, each with its own IMU.

    scale: the thesis 1920x1080 cameras at this fraction of their resolution (rendering speed).
    """

    simulated = True
    moving_camera = False      # the phantom's tissue plane follows the probe's depth: tracking would read it as slides
    description = "demo: rendered phantom, simulated IMU"

    def __init__(self, *, scale: float = 0.5, schedule: Schedule = Schedule(), fps: float = DEMO_FPS, seed: int = 0,
                 errors: ErrorModel | None = None):
        """``errors``: an error model (:mod:`snreg.demo.errors`) the rig runs with, drawn under ``seed``
        (:class:`~snreg.demo.error_rig.DemoErrors`); None: nothing errs but the render's noise (the ideal model)."""
        full = thesis_calibration()
        self.cameras = full.scaled(scale)                      # the simulated cameras as they truly are
        self.probe = default_probe_model()
        self.errors = DemoErrors(errors, self.probe, full, scale=scale, seed=seed) if errors is not None else None
        # what tracking uses (a calibration wizard replaces it): under an error model, one solved from noisy corners
        self.calibration = self.cameras if self.errors is None or self.errors.calibration is None else self.errors.calibration
        # the set-up as it happened, the endoscope's IMU there, and the chain referenced at it
        self.setup_deg = (TRUE_TILT_DEG, TRUE_TURN_DEG) if self.errors is None else self.errors.setup_deg
        self.earth_from_imu = endoscope_orientation(self.setup_deg)
        self.chain = still_demo_chain(self.earth_from_imu)
        self.schedule, self.fps, self.seed = schedule, fps, seed
        self.scene: PhantomScene | None = None
        self._folder = tempfile.TemporaryDirectory(prefix="snreg-demo-imu-")
        self._link = Path(self._folder.name) / "imu"
        attitude = ",".join(f"{v:.6f}" for v in euler_from_rotation(self.earth_from_imu))
        self._simulator = subprocess.Popen(
            [sys.executable, "-m", "snreg.cli", "imu", "simulate", "--still", f"--attitude={attitude}", "--seed",
             str(seed), "--port-link", str(self._link), "--parent", str(os.getpid())],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        self.imu = ImuMonitor(str(self._link))

    def frame_source(self) -> FrameSource:
        """The rendered stereo feed; call it in the worker thread (the IMU process starting and the scene
        pre-rendering take seconds). Raises OSError when the IMU simulator did not come up."""
        self._start_imu()
        if self.scene is None:                  # rendered once: a restart after a calibration replays the same tour
            options = {} if self.errors is None else {"noise_sigma": self.errors.noise_sigma,
                                                       "blur_sigma_px": self.errors.blur_px,
                                                       "tip_offsets_mm": self.errors.tip_offsets_mm}
            scene = PhantomScene(self.cameras, self.probe, self.schedule, seed=self.seed, **options)
            scene.prerender()
            self.scene = scene
        # a camera (DESIGN.md §3): frames stamped at grab on the host clock of the IMU samples and stored nodes, and
        # skipped when tracking falls behind, while the scene goes on at its own pace
        return CallableSource(self.scene.render, self.fps, live=True, name="Demo phantom")

    def phantom_sources_lps(self) -> np.ndarray:
        """(4, 3) LPS mm: where the phantom's sources were when the SPECT was made (the truth the demo's SPECT images)."""
        shift = 0.0 if self.errors is None else self.errors.scan_shift_mm
        return true_sources_lps(phantom_tips(self.probe), self.chain, setup_deg=self.setup_deg, scan_shift_mm=shift,
                                earth_from_imu=self.earth_from_imu)

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
        """Stop the IMU reader and its simulator process; call after the worker has stopped."""
        self.imu.stop()
        self._simulator.terminate()
        try:
            self._simulator.wait(5.0)
        except subprocess.TimeoutExpired:
            self._simulator.kill()
            self._simulator.wait()
        self._folder.cleanup()
