"""Rendered stereo video of a camera moving in surgery over tissue, with the IMU it would report and the truth.

Why: :mod:`snreg.odometry` is measured against sequences whose insertion is known (issue 27): the tissue of
:mod:`snreg.demo.tissue` fixed in the trocar frame, seen along a :class:`~snreg.demo.camera_path.CameraPath`, the
probe moving in view (its tip circling ahead of the camera, fixed in the trocar frame, so it moves against the
tissue in the image as the camera moves), sensor noise, the IMU's orientation with its noise, and pairs whose
view is covered (a uniform frame: the lens in tissue or smoke; or heavy blur). :meth:`SurgeryVideo.write` saves
it as ``snreg track-camera`` reads it: ``left/NNNN.png``, ``right/NNNN.png``, ``imu.csv`` (yaw, pitch, roll of
``earth_from_imu`` per pair), ``chain.json`` (its ``trocar_camera_mm`` the insertion at the first pair) and
``truth.csv`` (the true insertion, and whether the pair is covered or blurred). :func:`surgery_chain` is a chain
whose axes are all turned against each other (IMU, camera, trocar, earth), so no convention slip goes unseen.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from snreg.chain import THESIS_IMU_TROCAR_MM, THESIS_TROCAR_CAMERA_MM, ChainCalibration
from snreg.demo.camera_path import CameraPath
from snreg.demo.pivot_scene import DEFAULT_EARTH_FROM_TROCAR, DEFAULT_IMU_FROM_CAMERA
from snreg.demo.renderer import ProbePose, RenderOptions
from snreg.demo.tissue import TissueScene
from snreg.files import atomic_write
from snreg.geometry import euler_from_rotation, make_transform

__all__ = ["VideoOptions", "SurgeryVideo", "surgery_chain"]


@dataclass(frozen=True)
class VideoOptions:
    """``imu_noise_deg``: sd per axis of the IMU's orientation error; sensor noise (grey levels) and blur (px of the
    rendered size); ``probe``: draw it; ``covered``: pairs whose view is covered (a uniform frame: the lens in tissue,
    smoke); ``blurred``: pairs blurred heavily (Gaussian, 20 px at 1920 wide); ``probe_ahead_mm``: the probe tip's distance in
    front of the tissue; everything drawn from ``seed``."""

    imu_noise_deg: float = 0.2
    noise_sigma: float = 2.0
    blur_sigma_px: float = 0.0
    probe: bool = True
    covered: tuple[int, ...] = ()
    blurred: tuple[int, ...] = ()
    probe_ahead_mm: float = 12.0
    seed: int = 0

    def hidden(self, index: int) -> bool:
        """Whether pair ``index`` shows no usable tissue (covered or blurred)."""
        return index in self.covered or index in self.blurred


def surgery_chain(trocar_camera_mm: float = THESIS_TROCAR_CAMERA_MM) -> ChainCalibration:
    """The thesis' distances with the IMU turned on the camera head and the patient tilted against gravity (the pivot
    scene's axes): the true chain of the rendered videos."""
    camera_in_imu = DEFAULT_IMU_FROM_CAMERA @ [0.0, 0.0, THESIS_IMU_TROCAR_MM + trocar_camera_mm]
    return ChainCalibration(make_transform(DEFAULT_IMU_FROM_CAMERA, camera_in_imu), THESIS_IMU_TROCAR_MM,
                            make_transform(DEFAULT_EARTH_FROM_TROCAR.T, np.zeros(3)))


@dataclass(eq=False)
class SurgeryVideo:
    """Pairs ``0 .. len(path) - 1`` of ``scene`` seen along ``path`` on the true chain ``chain``."""

    scene: TissueScene
    path: CameraPath
    chain: ChainCalibration
    options: VideoOptions = field(default_factory=VideoOptions)

    def __len__(self) -> int:
        return len(self.path)

    def trocar_from_camera(self, index: int) -> np.ndarray:
        return self.path.trocar_from_camera(index, self.chain)

    def insertion_mm(self, index: int) -> float:
        return float(self.path.insertion_mm[index])

    def earth_from_imu(self, index: int) -> np.ndarray:
        """(3, 3) what the IMU reports at pair ``index``: the truth turned by its noise."""
        rng = np.random.default_rng([self.options.seed, 41, index])
        noise = Rotation.from_rotvec(np.radians(rng.normal(0.0, self.options.imu_noise_deg, 3))).as_matrix()
        return self.path.earth_from_imu(index, self.chain) @ noise

    def probe_pose(self, index: int) -> ProbePose | None:
        """The probe in the left camera frame at pair ``index`` (None when not drawn): its tip circles 10 mm about a
        point ``probe_ahead_mm`` before the tissue on the trocar axis, its body towards the camera's side."""
        if not self.options.probe:
            return None
        phase = 2.0 * np.pi * index / 40.0
        tip = np.array([6.0 + 10.0 * np.cos(phase), 4.0 + 10.0 * np.sin(phase),
                        self.scene.surface.depth_mm - self.options.probe_ahead_mm])
        axis = np.array([0.75, -0.35, -0.55])
        pose = self.trocar_from_camera(index)
        rotation, centre = pose[:3, :3], pose[:3, 3]
        return ProbePose.make(rotation.T @ (tip - centre), rotation.T @ axis)

    def pair(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right BGR frames of pair ``index``."""
        o = self.options
        options = RenderOptions(noise_sigma=o.noise_sigma, blur_sigma_px=o.blur_sigma_px, seed=o.seed * 100003 + index)
        if index in o.covered:
            rng = np.random.default_rng([o.seed, 43, index])
            width, height = self.scene.renderer.calibration.image_size
            grey = rng.uniform(40, 200) + rng.normal(0.0, o.noise_sigma, (2, height, width, 1))
            level = np.clip(grey * np.array([0.8, 0.9, 1.2]), 0, 255).astype(np.uint8)
            return level[0], level[1]
        if index in o.blurred:
            width = self.scene.renderer.calibration.image_size[0]
            options = RenderOptions(noise_sigma=o.noise_sigma, blur_sigma_px=20.0 * width / 1920, seed=options.seed)
        return self.scene.render(self.trocar_from_camera(index), self.probe_pose(index), options)

    def write(self, folder: str | Path) -> Path:
        """Save the video as ``snreg track-camera`` reads it (see the module docstring); returns the folder."""
        folder = Path(folder)
        for eye in ("left", "right"):
            (folder / eye).mkdir(parents=True, exist_ok=True)
        for index in range(len(self)):
            for eye, image in zip(("left", "right"), self.pair(index)):
                if not cv2.imwrite(str(folder / eye / f"{index:04d}.png"), image):
                    raise OSError(f"could not write {folder / eye / f'{index:04d}.png'}")
        angles = [euler_from_rotation(self.earth_from_imu(k)) for k in range(len(self))]
        with atomic_write(folder / "imu.csv") as temporary:
            temporary.write_text("yaw,pitch,roll\n" + "".join(f"{y:.6f},{p:.6f},{r:.6f}\n" for y, p, r in angles))
        start = self.chain.with_insertion(self.insertion_mm(0)) if len(self) else self.chain
        with atomic_write(folder / "chain.json") as temporary:
            temporary.write_text(json.dumps({**start.to_dict(), "method": "rendered"}) + "\n")
        with atomic_write(folder / "truth.csv") as temporary:
            temporary.write_text("index,trocar_camera_mm,covered\n" + "".join(
                f"{k},{self.insertion_mm(k):.6f},{int(self.options.hidden(k))}\n" for k in range(len(self))))
        return folder
