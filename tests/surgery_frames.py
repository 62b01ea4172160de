"""Rendered stereo pairs of a camera that slides through the trocar over tissue fixed in the trocar frame, with the
probe held on a node (fixed in the trocar frame too), for the tests of the chain over time (issue 27): the truth of
every pair is known (the insertion, the tip in both frames, the IMU orientation)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.camera import thesis_calibration
from snreg.demo.camera_path import CameraPath
from snreg.demo.renderer import ProbePose, RenderOptions
from snreg.demo.surgery_video import surgery_chain
from snreg.demo.tissue import TissueScene, TissueSurface
from snreg.probe import default_probe_model
from snreg.sources import StereoFrame
from snreg.workflow.acquisition import ImuReading

START_MM = 158.0
SCALE = 0.25                        # 480 x 270: fast renders; the probe and the tissue are still tracked
PERIOD_NS = 33_333_333              # 30 pairs a second
PROBE_AXIS = np.array([0.75, -0.35, -0.55]) / np.linalg.norm([0.75, -0.35, -0.55])    # trocar frame, tip to body
NODE_A = np.array([6.0, 4.0, 233.0])          # two node positions in the trocar frame, mm, 12-15 mm before the tissue
NODE_B = np.array([-14.0, 10.0, 230.0])


@dataclass(frozen=True, eq=False)
class Pair:
    """One rendered pair with its truth: the frame, the IMU reading at it, the insertion, the tip in the trocar frame."""

    frame: StereoFrame
    imu: ImuReading
    insertion_mm: float
    tip_trocar: np.ndarray | None


class SlidingWorld:
    """The thesis' rig at a quarter of its resolution on :func:`~snreg.demo.surgery_video.surgery_chain` over seeded
    tissue; :meth:`pair` renders the camera at an insertion (turned about the pivot by ``turn_deg``, a rotation
    vector in degrees in the trocar frame) with the probe tip on ``tip_trocar`` (None: no probe), or a covered view."""

    def __init__(self):
        self.calibration = thesis_calibration().scaled(SCALE)
        self.probe = default_probe_model()
        self.scene = TissueScene(self.calibration, self.probe, TissueSurface(depth_mm=245.0, seed=3, texture_seed=11))
        self.chain = surgery_chain(START_MM)

    def pose(self, insertion_mm: float, turn_deg=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
        """(trocar_from_camera (4, 4), earth_from_imu (3, 3)) of the camera at this insertion and turn."""
        path = CameraPath(np.array([float(insertion_mm)]), Rotation.from_rotvec([np.radians(turn_deg)]), np.zeros(1))
        return path.trocar_from_camera(0, self.chain), path.earth_from_imu(0, self.chain)

    def pair(self, index: int, insertion_mm: float, tip_trocar=None, *, turn_deg=(0.0, 0.0, 0.0), covered=False,
             imu_turn_deg=(0.0, 0.0, 0.0), t_ns: int | None = None) -> Pair:
        """Pair ``index`` grabbed at ``t_ns`` (default ``index`` periods); ``covered``: a uniform frame (the lens in
        tissue); ``imu_turn_deg``: the IMU reports the camera turned by this much more (a rotation vector, degrees,
        in the sensor frame)."""
        pose, earth_from_imu = self.pose(insertion_mm, turn_deg)
        t_ns = index * PERIOD_NS if t_ns is None else int(t_ns)
        if covered:
            width, height = self.calibration.image_size
            grey = np.random.default_rng([index, 43]).normal(120.0, 2.0, (2, height, width, 1))
            left, right = np.clip(grey * np.array([0.8, 0.9, 1.2]), 0, 255).astype(np.uint8)
        else:
            probe = None
            if tip_trocar is not None:
                rotation, centre = pose[:3, :3], pose[:3, 3]
                probe = ProbePose.make(rotation.T @ (np.asarray(tip_trocar) - centre), rotation.T @ PROBE_AXIS)
            left, right = self.scene.render(pose, probe, RenderOptions(noise_sigma=2.0, seed=index))
        imu = earth_from_imu @ Rotation.from_rotvec(np.radians(imu_turn_deg)).as_matrix()
        return Pair(StereoFrame(left, right, t_ns, t_ns + 2000, index), ImuReading(imu), float(insertion_mm),
                    None if tip_trocar is None or covered else np.asarray(tip_trocar, dtype=float))


def slide_then_rest(world: SlidingWorld, *, rest: int = 4, to_mm: float = START_MM + 20.0,
                    step_mm: float = 5.0) -> list[Pair]:
    """The probe held on node A with the camera at the start, the camera slid to ``to_mm`` while the probe moves to
    node B, then held on node B: ``rest`` pairs at each end."""
    pairs = [world.pair(k, START_MM, NODE_A) for k in range(rest)]
    steps = np.arange(START_MM + step_mm, to_mm + step_mm / 2, step_mm)
    for k, insertion in enumerate(steps):
        share = (k + 1) / len(steps)
        pairs.append(world.pair(len(pairs), insertion, NODE_A + share * (NODE_B - NODE_A)))
    for _ in range(rest):
        pairs.append(world.pair(len(pairs), to_mm, NODE_B))
    return pairs
