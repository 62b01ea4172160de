"""The hardware-free rig of ``snreg-gui --demo``: simulated devices wired through the real code paths.

Why: the demo and the GUI tests must exercise what a phantom session runs (a frame source read and
tracked, an IMU on a serial port read by :class:`SerialImuReader` and fused, the camera-to-trocar
chain), only with rendered frames and a simulated IMU on a pseudo-terminal. The session file is not the
rig's: whoever runs it (the app, the headless demo) creates it.
The IMU is held still and level, so the trocar frame is the camera frame shifted by the trocar-camera
distance along the shaft, which the tests use as ground truth.
"""

from __future__ import annotations

import time

from snreg.calibration import thesis_calibration
from snreg.chain import ChainCalibration
from snreg.imu import ImuSimulator, MotionProfile, SimulatedPort, still
from snreg.sources import CallableSource, FrameSource
from snreg.tracking import default_probe_model
from snreg.demo.scene import PhantomScene, Schedule
from snreg.imu.monitor import ImuMonitor

DEMO_FPS = 30.0


class DemoRig:
    """Calibration, chain, simulated IMU (started); :meth:`frame_source` builds the rendered feed.

    scale: the thesis 1920x1080 cameras at this fraction of their resolution (rendering speed).
    """

    def __init__(self, *, scale: float = 0.5,
                 schedule: Schedule = Schedule(), fps: float = DEMO_FPS, seed: int = 0):
        self.calibration = thesis_calibration().scaled(scale)
        self.probe = default_probe_model()
        self.chain = ChainCalibration.manual()
        self.schedule, self.fps, self.seed = schedule, fps, seed
        self.scene: PhantomScene | None = None
        self._port = SimulatedPort(ImuSimulator(MotionProfile([still(1.0)]), seed=seed)).start()
        self.imu = ImuMonitor(self._port.port).start()

    def frame_source(self) -> FrameSource:
        """The rendered stereo feed; call it in the worker thread (building and pre-rendering the scene takes seconds)."""
        scene = PhantomScene(self.calibration, self.probe, self.schedule, seed=self.seed)
        scene.prerender()
        self.scene = scene
        # frame times on the host clock of the IMU samples and stored nodes (DESIGN.md §3), from now at the nominal rate
        return CallableSource(self.scene.render, self.fps, start_ns=time.perf_counter_ns(), name="Demo phantom")

    def close(self) -> None:
        """Stop the IMU; call after the worker has stopped."""
        self.imu.stop()
        self._port.stop()
