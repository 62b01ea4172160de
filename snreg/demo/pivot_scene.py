"""A simulated pivot recording with ground truth: the endoscope pivoting in its trocar in front of a still board.

Why: the trocar wizard (``snreg_gui.wizards.trocar.wizard``) and its tests need live left/right frames of a
checkerboard together with an IMU whose orientation belongs to the frame on screen, with the true
trocar-camera distance and IMU-camera rotation known. The wizard's code after the source and the IMU
is the same as with a camera and an :class:`~snreg.imu.monitor.ImuMonitor`; only the devices differ.

Geometry (docs/design.md, Conventions): the trocar frame has its origin at the pivot and z along the shaft into the
patient; in the reference pose the camera sits at ``z = trocar_camera_mm`` looking along +z, and the
board faces it ``board_distance_mm`` further in, centred on the axis. Once per cycle of
``frames_per_cycle`` frames the shaft traces an ellipse about the axis: tilted ``tilt_deg[0]`` degrees
left and right (a turn about the trocar's y axis) and ``tilt_deg[1]`` up and down (about x), without
rolling about itself, so every step is the swing that the thesis's arc method (eq. 14) assumes. The IMU
is mounted at ``imu_from_camera`` (a rotation) ``imu_trocar_mm`` behind the pivot; the patient lies at
``earth_from_trocar``, so ``earth_from_imu = earth_from_trocar @ trocar_from_camera @ camera_from_imu``.

Rendering costs ~0.1 s per pair at half the thesis resolution, so every frame of the cycle is rendered
once (sensor noise seeded by ``seed`` and the frame) and replayed from memory; :meth:`PivotScene.frame_source`
does it before the feed starts (a few seconds for 90 frames). Usage::

    scene = PivotScene(thesis_calibration().scaled(0.5), Board(10, 7, 10.0))
    source, imu = scene.frame_source(), scene.imu     # imu.snapshot() follows the last frame read
    scene.true_chain.trocar_camera_mm                 # 158.0
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.calibration.checkerboard import Board
from snreg.camera import StereoCalibration
from snreg.chain import THESIS_IMU_TROCAR_MM, THESIS_TROCAR_CAMERA_MM, ChainCalibration
from snreg.demo.board_render import render_stereo_board
from snreg.geometry import euler_from_rotation, invert, make_transform
from snreg.imu.monitor import ImuAt, ImuSnapshot
from snreg.sources import CallableSource

__all__ = ["PivotScene", "SceneImu", "DEFAULT_IMU_FROM_CAMERA", "DEFAULT_EARTH_FROM_TROCAR"]

# the IMU on the camera head, axes turned against the camera's (the thesis aligned them by eye)
DEFAULT_IMU_FROM_CAMERA = Rotation.from_euler("ZYX", [30.0, -10.0, 100.0], degrees=True).as_matrix()
# the patient's trocar axis against gravity: tilted 40 degrees, turned 12 degrees in heading
DEFAULT_EARTH_FROM_TROCAR = Rotation.from_euler("ZYX", [12.0, 40.0, -3.0], degrees=True).as_matrix()


class PivotScene:
    """Rendered left/right frames of a still board while the endoscope pivots, with the IMU and the true chain.

    ``calibration``: the stereo cameras (at the resolution to render); ``board``: the checkerboard.
    Distances in mm, angles in degrees; see the module docstring for the motion. The frame index
    cycles, so frame ``k`` and frame ``k + frames_per_cycle`` are the same.
    """

    def __init__(self, calibration: StereoCalibration, board: Board, *, frames_per_cycle: int = 90,
                 tilt_deg: tuple[float, float] = (10.0, 6.0), trocar_camera_mm: float = THESIS_TROCAR_CAMERA_MM,
                 imu_trocar_mm: float = THESIS_IMU_TROCAR_MM, board_distance_mm: float = 250.0,
                 imu_from_camera: np.ndarray = DEFAULT_IMU_FROM_CAMERA,
                 earth_from_trocar: np.ndarray = DEFAULT_EARTH_FROM_TROCAR,
                 noise_sigma: float = 2.0, blur_sigma: float = 0.7, seed: int = 0):
        if frames_per_cycle < 8:
            raise ValueError(f"a pivot cycle needs at least 8 frames, got {frames_per_cycle}")
        self.calibration, self.board = calibration, board
        self.frames_per_cycle = int(frames_per_cycle)
        self.trocar_camera_mm = float(trocar_camera_mm)
        self.imu_from_camera = np.asarray(imu_from_camera, dtype=float)
        self.earth_from_trocar = np.asarray(earth_from_trocar, dtype=float)
        self.noise_sigma, self.blur_sigma, self.seed = noise_sigma, blur_sigma, seed
        camera_in_imu = self.imu_from_camera @ [0.0, 0.0, trocar_camera_mm + imu_trocar_mm]
        self.true_chain = ChainCalibration(make_transform(self.imu_from_camera, camera_in_imu), imu_trocar_mm)
        azimuth = 2.0 * np.pi * np.arange(self.frames_per_cycle) / self.frames_per_cycle
        left_right, up_down = np.radians(tilt_deg)
        turns = Rotation.from_rotvec(np.c_[up_down * np.sin(azimuth), left_right * np.cos(azimuth),
                                           np.zeros_like(azimuth)])
        self._trocar_from_camera = make_transform(turns.as_matrix(), turns.apply([0.0, 0.0, trocar_camera_mm]))
        centre = np.array([(board.cols - 1) / 2.0, (board.rows - 1) / 2.0, 0.0]) * board.square_mm
        self.trocar_from_board = make_transform(np.eye(3), [0.0, 0.0, trocar_camera_mm + board_distance_mm] - centre)
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.shown_index = 0
        self.imu = SceneImu(self)

    def trocar_from_camera(self, index: int) -> np.ndarray:
        """(4, 4) true camera pose at frame ``index`` in the trocar frame, mm."""
        return self._trocar_from_camera[index % self.frames_per_cycle].copy()

    def board_from_camera(self, index: int) -> np.ndarray:
        """(4, 4) true camera pose at frame ``index`` in the board frame, mm (what solvePnP measures)."""
        return invert(self.trocar_from_board) @ self.trocar_from_camera(index)

    def earth_from_imu(self, index: int) -> np.ndarray:
        """(3, 3) true IMU orientation at frame ``index`` (sensor to earth, as an AHRS gives it)."""
        return self.earth_from_trocar @ self.trocar_from_camera(index)[:3, :3] @ self.imu_from_camera.T

    def render(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right BGR frames of frame ``index`` (a ``CallableSource`` callback); the IMU then shows it."""
        key = index % self.frames_per_cycle
        if key not in self._cache:
            self._cache[key] = render_stereo_board(
                self.calibration, self.board, invert(self.trocar_from_camera(key)) @ self.trocar_from_board,
                noise_sigma=self.noise_sigma, blur_sigma=self.blur_sigma, seed=self.seed + key, bgr=True)
        self.shown_index = index
        return self._cache[key]

    def prerender(self) -> None:
        """Render every frame of the cycle once (~0.1 s each at half resolution), so :meth:`render` only replays."""
        for index in range(self.frames_per_cycle):
            self.render(index)
        self.shown_index = 0

    def frame_source(self, fps: float = 30.0) -> CallableSource:
        """An endless feed of the cycle, repeated, pre-rendered first (at once when it already is); read it from
        one thread, with :attr:`imu` snapshots in between."""
        self.prerender()
        return CallableSource(self.render, fps, name="Simulated pivot recording")


class SceneImu:
    """The IMU stand-in (a :class:`~snreg.rig.protocols.Imu`): :meth:`snapshot` gives the orientation at the frame
    the scene rendered last. ``scene``: anything with ``earth_from_imu(index)`` and ``shown_index``, as
    :class:`PivotScene` and :class:`~snreg.demo.tissue_pivot.TissuePivotScene`.

    A wizard that takes a snapshot right after reading a frame pairs the two exactly, as it would a camera frame
    with the IMU at the frame's host time. It has no raw samples to record.
    """

    def __init__(self, scene):
        self._scene = scene

    def start(self) -> "SceneImu":
        return self

    def stop(self) -> None:
        """Nothing to stop: the orientation comes from the scene."""

    def take_samples(self) -> list:
        return []

    def orientation_at(self, t_host_ns: int) -> ImuAt:
        """The orientation at the frame the scene rendered last (the wizard asks right after reading it)."""
        return ImuAt(self._scene.earth_from_imu(self._scene.shown_index), 0.0, "open")

    def snapshot(self) -> ImuSnapshot:
        index = self._scene.shown_index
        rotation = self._scene.earth_from_imu(index)
        return ImuSnapshot("open", "", 208.0, 0.0, euler_from_rotation(rotation), rotation, index + 1, 0)
