"""The demo phantom: the probe visiting four sentinel-node positions and resting on each, rendered in stereo.

Why: the acquisition screen needs a live feed with a known truth and no hardware. The probe rests on
node k for ``rest_frames`` frames, then glides to node k+1 over ``move_frames`` frames, and the cycle
repeats. Rendering costs ~0.15 s per pose at half resolution, so each pose is rendered once
(sensor-noise exposures of each eye per resting pose, paired apart frame by frame by
:class:`~snreg.demo.rest_exposures.RestExposures`; one per moving pose) and then replayed from memory;
:meth:`PhantomScene.prerender` does it all before the feed starts, because rendering holds the GIL
in bursts long enough to stall the GUI thread.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.camera import StereoCalibration
from snreg.demo.renderer import ProbePose, RenderOptions, StereoRenderer
from snreg.demo.rest_exposures import RestExposures
from snreg.probe import ProbeModel

_AXIS = np.array([1.0, -0.35, 0.4])        # probe pointing right, up and away: a side view the tracker reads
PROBE_AXIS = _AXIS / np.linalg.norm(_AXIS)  # unit axis, tip to body, camera frame
# stripe-band centres of the four phantom nodes, left camera frame (mm)
NODE_CENTRES_MM = np.array([[-18.0, -6.0, 85.0], [16.0, -4.0, 92.0], [14.0, 8.0, 118.0], [-16.0, 6.0, 110.0]])


def phantom_tips(probe: ProbeModel) -> np.ndarray:
    """(4, 3) probe tips (left camera frame, mm) resting on the four phantom nodes: where the sources are."""
    axis = _AXIS / np.linalg.norm(_AXIS)
    return NODE_CENTRES_MM - probe.band_centre_mm * axis


@dataclass(frozen=True)
class Schedule:
    """Frames spent resting on each node and moving to the next; ``noise_variants`` exposures of each eye per rest,
    paired apart (:class:`~snreg.demo.rest_exposures.RestExposures`: ``noise_variants ** 2`` distinct pairs)."""

    rest_frames: int = 90
    move_frames: int = 5
    noise_variants: int = 16

    @property
    def cycle(self) -> int:
        return len(NODE_CENTRES_MM) * (self.rest_frames + self.move_frames)


class PhantomScene:
    """Rendered stereo frames of the probe along the node tour; ``truth_tip`` and ``resting_node`` give ground truth."""

    def __init__(self, calibration: StereoCalibration, probe: ProbeModel, schedule: Schedule = Schedule(),
                 noise_sigma: float = 2.0, seed: int = 0, blur_sigma_px: float = 0.0, tip_offsets_mm=None):
        """``tip_offsets_mm`` (4, 3): where the probe rests on each node relative to the node (camera frame, mm;
        the error model's pointing and what the demo cannot run through code), none by default."""
        self.schedule, self.noise_sigma, self.blur_sigma_px, self.seed = schedule, noise_sigma, blur_sigma_px, seed
        self.renderer = StereoRenderer(calibration, probe)
        tips = phantom_tips(probe) + (0.0 if tip_offsets_mm is None else np.asarray(tip_offsets_mm, float))
        self.node_poses = [ProbePose.make(tip, PROBE_AXIS) for tip in tips]
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}       # moving frames by frame in the cycle
        self._rests: dict[int, RestExposures] = {}

    @property
    def cycle(self) -> int:
        """Frames in one tour of the nodes (the frame index repeats after it)."""
        return self.schedule.cycle

    def resting_node(self, index: int) -> int | None:
        """The node the probe rests on at frame ``index``, None while it moves."""
        node, step = divmod(index % self.schedule.cycle, self.schedule.rest_frames + self.schedule.move_frames)
        return node if step < self.schedule.rest_frames else None

    def pose(self, index: int) -> ProbePose:
        """The true probe pose at frame ``index``: a node while resting, a straight glide between nodes otherwise."""
        node, step = divmod(index % self.schedule.cycle, self.schedule.rest_frames + self.schedule.move_frames)
        here = self.node_poses[node]
        if step < self.schedule.rest_frames:
            return here
        there = self.node_poses[(node + 1) % len(self.node_poses)]
        u = (step - self.schedule.rest_frames + 1) / (self.schedule.move_frames + 1)
        return ProbePose.make(here.tip + u * (there.tip - here.tip), here.axis)

    def truth_tip(self, node: int) -> np.ndarray:
        """(3,) true tip of node ``node`` in the left camera frame, mm."""
        return self.node_poses[node].tip.copy()

    def prerender(self) -> None:
        """Render every frame of the tour once (~3 s at half resolution), so :meth:`render` only replays."""
        for index in range(self.schedule.cycle):
            self.render(index)

    def render(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right BGR frames for frame ``index`` (a ``CallableSource`` callback)."""
        resting = self.resting_node(index)
        if resting is not None:
            if resting not in self._rests:
                seed = self.seed * 10**5 + (resting + 1) * 10**4
                self._rests[resting] = RestExposures(self.renderer.radiance(self.pose(index), self._options(seed)),
                                                     self._expose, self.schedule.noise_variants, seed)
            return self._rests[resting].pair(index)
        cycle_index = index % self.schedule.cycle
        if cycle_index not in self._cache:
            options = self._options(self.seed + cycle_index)
            self._cache[cycle_index] = self.renderer.expose(self.renderer.radiance(self.pose(index), options), options)
        return self._cache[cycle_index]

    def _options(self, seed: int) -> RenderOptions:
        return RenderOptions(noise_sigma=self.noise_sigma, blur_sigma_px=self.blur_sigma_px, seed=seed)

    def _expose(self, radiance, seed: int) -> tuple[np.ndarray, np.ndarray]:
        return self.renderer.expose(radiance, self._options(seed))
