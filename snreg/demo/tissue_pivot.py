"""A simulated recording of the camera turning about the trocar over tissue, with its IMU and the true chain.

Why: the trocar wizard's third method ("turn the camera over tissue", :mod:`snreg.calibration.tissue_pivot`), its
tests, ``snreg calibrate trocar tissue`` and ``snreg experiment tissue-pivot`` need stereo pairs of still tissue
(:mod:`snreg.demo.tissue`) seen by a camera that pivots about the trocar at a fixed insertion, with the IMU's
orientation that belongs to each pair and the true trocar-camera distance known. It is
:class:`~snreg.demo.pivot_scene.PivotScene` over tissue instead of a board: once per cycle of ``frames_per_cycle``
pairs the shaft traces an ellipse of tilts about the trocar axis (``tilt_deg``: left-right, up-down), without
sliding; the IMU reports each pair's orientation with ``imu_noise_deg`` of noise per axis; the probe in view moves
against the tissue; the chain's axes are all turned against each other (:func:`~snreg.demo.surgery_video.surgery_chain`).
The pairs come from :class:`~snreg.demo.surgery_video.SurgeryVideo`, which also writes them as files.

A pair costs about 0.15 s to render at a quarter of the thesis resolution and 0.7 s at half, so the feed renders
each frame of the cycle when first read and replays it afterwards (the first cycle is slow, as a camera is not); the
tissue itself is built at the first frame (seconds), in the thread that reads the feed.
"""

from __future__ import annotations

import threading

import numpy as np
from scipy.spatial.transform import Rotation

from snreg.camera import StereoCalibration
from snreg.chain import THESIS_TROCAR_CAMERA_MM
from snreg.demo.camera_path import CameraPath
from snreg.demo.pivot_scene import SceneImu
from snreg.demo.renderer import ProbePose
from snreg.demo.surgery_video import SurgeryVideo, VideoOptions, surgery_chain
from snreg.demo.tissue import TissueScene, TissueSurface
from snreg.probe import default_probe_model
from snreg.sources import CallableSource

__all__ = ["pivot_cycle", "TissuePivotScene"]

DEFAULT_SURFACE = TissueSurface(depth_mm=245.0, seed=3, texture_seed=11)     # tissue about 85 mm ahead


def pivot_cycle(n_pairs: int, insertion_mm: float, tilt_deg: tuple[float, float] = (10.0, 6.0)) -> CameraPath:
    """``n_pairs`` poses of one cycle about the pivot at ``insertion_mm``: the shaft tilted ``tilt_deg[0]`` degrees
    left and right (about the trocar's y axis) and ``tilt_deg[1]`` up and down (about x), on an ellipse that starts
    tilted fully to one side; no slide and no roll. The shaft's orientation spread is twice the larger tilt."""
    if n_pairs < 8:
        raise ValueError(f"a pivot cycle needs at least 8 pairs, got {n_pairs}")
    azimuth = 2.0 * np.pi * np.arange(n_pairs) / n_pairs
    left_right, up_down = np.radians(tilt_deg)
    turns = Rotation.from_rotvec(np.c_[up_down * np.sin(azimuth), left_right * np.cos(azimuth), np.zeros(n_pairs)])
    return CameraPath(np.full(n_pairs, float(insertion_mm)), turns, np.zeros(n_pairs))


class TissuePivotScene:
    """Rendered pairs of still tissue while the endoscope pivots, with the IMU (:attr:`imu`) and the true chain.

    ``calibration``: the stereo cameras (the resolution rendered); distances in mm, angles in degrees; the frame index
    cycles, so frame ``k`` and frame ``k + frames_per_cycle`` are the same. ``probe``: draw the probe in view.
    """

    def __init__(self, calibration: StereoCalibration, *, frames_per_cycle: int = 36,
                 tilt_deg: tuple[float, float] = (10.0, 6.0), trocar_camera_mm: float = THESIS_TROCAR_CAMERA_MM,
                 surface: TissueSurface = DEFAULT_SURFACE, imu_noise_deg: float = 0.2, probe: bool = True,
                 seed: int = 0):
        self.calibration = calibration
        self.frames_per_cycle = int(frames_per_cycle)
        self.true_chain = surgery_chain(trocar_camera_mm)
        self._make_video = lambda: SurgeryVideo(
            TissueScene(calibration, default_probe_model(), surface),
            pivot_cycle(self.frames_per_cycle, trocar_camera_mm, tilt_deg), self.true_chain,
            VideoOptions(imu_noise_deg=imu_noise_deg, probe=probe, seed=seed))
        self._video: SurgeryVideo | None = None
        self._building = threading.Lock()
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self.shown_index = 0
        self.imu = SceneImu(self)

    @property
    def video(self) -> SurgeryVideo:
        """The rendered video of one cycle, built when first needed (seconds: the tissue's height field and texture),
        so a window can make the scene and leave the building to the capture thread."""
        with self._building:
            if self._video is None:
                self._video = self._make_video()
            return self._video

    def trocar_from_camera(self, index: int) -> np.ndarray:
        """(4, 4) true camera pose at frame ``index`` in the trocar frame, mm."""
        return self.video.trocar_from_camera(index % self.frames_per_cycle)

    def earth_from_imu(self, index: int) -> np.ndarray:
        """(3, 3) what the IMU reports at frame ``index``: the truth turned by its noise (the same at each cycle)."""
        return self.video.earth_from_imu(index % self.frames_per_cycle)

    def probe_pose(self, index: int) -> ProbePose | None:
        """The probe in the left camera frame at frame ``index`` (None when not drawn)."""
        return self.video.probe_pose(index % self.frames_per_cycle)

    def render(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right BGR frames of frame ``index`` (a ``CallableSource`` callback); the IMU then shows it."""
        key = index % self.frames_per_cycle
        if key not in self._cache:
            self._cache[key] = self.video.pair(key)
        self.shown_index = index
        return self._cache[key]

    def frame_source(self, fps: float = 30.0) -> CallableSource:
        """An endless feed of the cycle, repeated; read it from one thread, with :attr:`imu` snapshots in between."""
        return CallableSource(self.render, fps, name="Simulated turn over tissue")
