"""The surgery demo's scene: the phantom's four nodes on tissue fixed in the trocar frame, the probe resting on each in
turn, seen by a camera that slides through the trocar and turns about the pivot between rests.

Why: ``snreg demo --camera surgery`` (and ``snreg-gui --demo --camera surgery``) must show that nodes stored while the
camera moves are as good as with the still camera of :mod:`snreg.demo.scene`, so the nodes are where that scene's
are: the same four probe tips, relative to the camera's start pose, now fixed in the trocar frame. The tissue
(:class:`~snreg.demo.tissue.TissueSurface`) is a bowl with relief whose surface passes through each tip (a mound or a
dip of tissue at each node). Those tips lie on a steep wall (they rise 25 mm towards the camera over 12 mm across
the view) and the probe leans away from the camera as in the still scene, so part of its body would lie inside the
tissue: it is drawn in front of it (``probe_in_front``), which keeps its view, and so its tracking, the still
scene's. At each rest the probe lies as in the still scene relative to the camera (its axis
:data:`~snreg.demo.scene.PROBE_AXIS` in the camera frame, the error model's tip offset in that camera's frame);
between rests it glides to the next node while the camera moves (:class:`~snreg.demo.camera_tour.CameraTour`).

The chain is the thesis' manual one with the endoscope held as the phantom's set-up holds it (looking caudally
34 degrees below the patient's coronal plane, :data:`~snreg.demo.phantom.TRUE_TILT_DEG`, on a table tilted 27 degrees
head down: a few degrees below the horizontal), so a turn left or right is mostly a turn about the vertical, which
the IMU measures with its gyroscope alone. Rendering a distinct frame costs ~0.12 s of CPU at half resolution (issue 36:
0.36-0.52 s before the tissue's cast was refined from a coarse one, the probe cast only round it and the noise drawn by
OpenCV; :mod:`snreg.demo.tissue`, :mod:`snreg.demo.renderer`), ~25 s for the tour, so every distinct frame
of the tour (one radiance per rest, exposed ``noise_variants`` times per eye and paired apart frame by frame; one
render per moving frame) is rendered once and replayed from memory: on first use (:meth:`SurgeryScene.render`), or
ahead of the play in tour order (:meth:`SurgeryScene.render_next`, which the demo rig runs beside the feed, so the
first frame need not wait for the whole tour: 10-30 s on a loaded machine).
"""

from __future__ import annotations

import threading

import numpy as np

from snreg.camera import StereoCalibration
from snreg.chain import ChainCalibration
from snreg.demo.camera_tour import CameraKey, CameraTour
from snreg.demo.phantom import TRUE_TILT_DEG, TRUE_TURN_DEG, endoscope_orientation
from snreg.demo.renderer import ProbePose, RenderOptions
from snreg.demo.rest_exposures import RestExposures
from snreg.demo.scene import PROBE_AXIS, Schedule, phantom_tips
from snreg.demo.tissue import TissueScene, TissueSurface
from snreg.geometry import apply, invert, make_transform
from snreg.probe import ProbeModel

__all__ = ["SurgeryScene", "REST_KEYS", "VIA_KEYS", "surgery_demo_chain", "surgery_tour"]

# where the camera rests while the probe rests on node n (the first: the start pose), and the keys it passes on the
# way to the next rest: every move slides 20 mm or more and turns 6 degrees or more, one by way of the camera drawn
# back 30 mm and turned 18 degrees, one by way of it pushed in 30 mm and then turned 14 degrees right, a look around
# that takes the fourth node, the one not found yet after three stores, out of the left image for about a second
# (the feeds' edge arrow); the stored nodes leave it then too, and otherwise every node stays in view
REST_KEYS = (CameraKey(0.0, (0.0, 0.0)), CameraKey(15.0, (-2.0, -6.0)), CameraKey(-10.0, (1.0, 2.0)),
             CameraKey(20.0, (-3.0, -8.0)))
VIA_KEYS = ((CameraKey(-30.0, (-2.0, -18.0)),), (), (CameraKey(30.0, (-2.0, -7.0)), CameraKey(30.0, (-2.0, 14.0))),
            ())
# the tissue: a bowl 245 mm from the pivot on the axis, tilted to recede down the view, through every node
_TISSUE = dict(depth_mm=245.0, tilt_deg=(5.7, 26.6), relief_mm=2.0, anchor_radius_mm=12.0)


def surgery_demo_chain(setup_deg: tuple[float, float] = (TRUE_TILT_DEG, TRUE_TURN_DEG)) -> ChainCalibration:
    """The thesis' manual chain (axes aligned, 460 + 158 mm) with the endoscope held as the phantom's set-up
    ``setup_deg`` (tilt, turn) holds it: looking caudally below the patient's coronal plane, image up anterior, the
    patient supine on the table tilted head down (:func:`~snreg.demo.phantom.endoscope_orientation`, so gravity in
    the trocar frame agrees with the SPECT's patient position); headed so the IMU's yaw starts at 0, as the AHRS's does
    (it has no compass)."""
    earth_from_trocar = endoscope_orientation(setup_deg)
    manual = ChainCalibration.manual()
    return ChainCalibration(manual.imu_from_camera, manual.imu_trocar_mm,
                            make_transform(earth_from_trocar.T, np.zeros(3)))


def surgery_tour(schedule: Schedule, chain: ChainCalibration) -> CameraTour:
    """The camera's tour of :data:`REST_KEYS` and :data:`VIA_KEYS` with ``schedule``'s rests, from ``chain``'s distance
    (cheap: what the IMU simulator plays is known before anything is rendered)."""
    return CameraTour(REST_KEYS, VIA_KEYS, rest_frames=schedule.rest_frames, start_mm=chain.trocar_camera_mm,
                      min_move_frames=schedule.move_frames)


class SurgeryScene:
    """Rendered stereo frames of the node tour seen by the moving camera, with its truth: ``resting_node``,
    ``trocar_from_camera``, ``earth_from_imu``, ``truth_trocar``; ``fps`` sets the tour's pace in seconds (the IMU's).

    ``tip_offsets_mm`` (4, 3): where the probe rests on each node relative to the node, in the camera frame of its
    rest (the error model's pointing and what the demo cannot run through code), none by default.
    """

    def __init__(self, calibration: StereoCalibration, probe: ProbeModel, schedule: Schedule = Schedule(), *,
                 chain: ChainCalibration | None = None, fps: float = 30.0, noise_sigma: float = 2.0, seed: int = 0,
                 blur_sigma_px: float = 0.0, tip_offsets_mm=None):
        self.schedule, self.fps, self.seed = schedule, float(fps), seed
        self.noise_sigma, self.blur_sigma_px = noise_sigma, blur_sigma_px
        self.chain = chain if chain is not None else surgery_demo_chain()
        self.tour = surgery_tour(schedule, self.chain)
        self.path = self.tour.path()
        start = self.path.trocar_from_camera(0, self.chain)
        tips = phantom_tips(probe)
        self.nodes_trocar = apply(start, tips)
        offsets = np.zeros_like(tips) if tip_offsets_mm is None else np.asarray(tip_offsets_mm, float)
        rests = [self.trocar_from_camera(first) for first in self.tour.rest_starts]
        rotations = np.array([pose[:3, :3] for pose in rests])
        self._rest_tips = self.nodes_trocar + np.einsum("nij,nj->ni", rotations, offsets)
        self._rest_axes = np.array([pose[:3, :3] @ PROBE_AXIS for pose in rests])
        surface = TissueSurface(**_TISSUE, anchors=tuple(tuple(float(v) for v in p) for p in self.nodes_trocar))
        self.tissue = TissueScene(calibration, probe, surface, probe_in_front=True)
        self._cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._rendering = threading.Lock()          # one render at a time: the feed and the renderer ahead share it
        self._distinct = len({self._key(index) for index in range(self.cycle)})

    @property
    def cycle(self) -> int:
        """Frames in one tour of the nodes (the frame index repeats after it)."""
        return self.tour.cycle

    def resting_node(self, index: int) -> int | None:
        """The node the probe rests on at frame ``index`` (the camera still), None while they move."""
        return self.tour.resting(index)

    def trocar_from_camera(self, index: int) -> np.ndarray:
        """(4, 4) the camera's true pose at frame ``index``."""
        return self.path.trocar_from_camera(index % self.cycle, self.chain)

    def earth_from_imu(self, index: int) -> np.ndarray:
        """(3, 3) the IMU's true orientation at frame ``index`` (what the simulated IMU plays at that instant)."""
        return self.path.earth_from_imu(index % self.cycle, self.chain)

    def truth_trocar(self, node: int) -> np.ndarray:
        """(3,) where node ``node`` is (the trocar frame, mm): the still scene's tip seen from the start pose."""
        return self.nodes_trocar[node].copy()

    def pose(self, index: int) -> ProbePose:
        """The probe in the left camera frame at frame ``index``: on a node while resting, gliding to the next (the
        tip along a straight line in the trocar frame) while the camera moves."""
        node, u = self.tour.move_progress(index)
        after = (node + 1) % len(self._rest_tips)
        tip = self._rest_tips[node] + u * (self._rest_tips[after] - self._rest_tips[node])
        axis = self._rest_axes[node] + u * (self._rest_axes[after] - self._rest_axes[node])
        camera_from_trocar = invert(self.trocar_from_camera(index))
        return ProbePose.make(apply(camera_from_trocar, tip[None])[0], camera_from_trocar[:3, :3] @ axis)

    @property
    def distinct_frames(self) -> int:
        """Distinct frames in one tour: what rendering it all takes."""
        return self._distinct

    @property
    def rendered(self) -> int:
        """Distinct frames rendered so far."""
        return len(self._cache)

    def prerender(self) -> None:
        """Render every frame of the tour once, so :meth:`render` only replays."""
        while self.render_next():
            pass

    def render_next(self, after: int = 0, within: int | None = None) -> bool:
        """Render the first distinct frame not rendered yet from frame ``after`` on in tour order (wrapping round),
        at most ``within`` frames ahead (None: anywhere); False when there is none (all rendered, or none that
        near)."""
        index = self.pending(after, within)
        if index is not None:
            self.render(index)
        return index is not None

    def pending(self, after: int = 0, within: int | None = None, done=None) -> int | None:
        """The first frame from ``after`` on in tour order (wrapping round), at most ``within`` frames ahead (None:
        anywhere), whose distinct frame's key (:meth:`distinct_key`) is not in ``done`` (default: those rendered
        here); None when there is none."""
        done = self._cache if done is None else done
        ahead = self.cycle if within is None else min(int(within), self.cycle)
        start = after % self.cycle
        for step in range(ahead):
            index = (start + step) % self.cycle
            if self._key(index) not in done:
                return index
        return None

    def distinct_key(self, index: int) -> tuple[int, int]:
        """The key of frame ``index``'s distinct frame: frames sharing it show one rendering."""
        return self._key(index)

    def render_distinct(self, index: int):
        """Frame ``index``'s distinct frame rendered now and not kept (the render process's; :meth:`keep` takes it
        in): a rest's :class:`~snreg.demo.rest_exposures.RestExposures` or a moving frame's (left, right)."""
        return self._render_distinct(index, self._key(index))

    def keep(self, key: tuple[int, int], rendered) -> None:
        """Take in a distinct frame rendered elsewhere (:meth:`render_distinct` of a scene made alike: the same
        frame, as the noise is seeded by its key); one rendered here already stays."""
        self._cache.setdefault(key, rendered)

    def render(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Left and right BGR frames for frame ``index`` (a ``CallableSource`` callback; thread-safe): a rest's
        exposures paired apart frame by frame (:class:`~snreg.demo.rest_exposures.RestExposures`), a moving frame as
        rendered."""
        key = self._key(index)
        rendered = self._cache.get(key)
        if rendered is None:
            with self._rendering:
                rendered = self._cache.get(key)         # rendered while this waited
                if rendered is None:
                    rendered = self._cache[key] = self._render_distinct(index, key)
        return rendered.pair(index) if isinstance(rendered, RestExposures) else rendered

    def _render_distinct(self, index: int, key: tuple[int, int]):
        if key[0] >= 0:                                 # a rest: one radiance, its exposures drawn apart
            seed = self.seed * 10**7 + (key[0] + 1) * 10**6
            radiance = self.tissue.radiance(self.trocar_from_camera(index), self.pose(index), self._options(seed))
            return RestExposures(radiance, self._expose, self.schedule.noise_variants, seed)
        return self.tissue.render(self.trocar_from_camera(index), self.pose(index),
                                  self._options(self.seed * 10**7 + key[1]))

    def _options(self, seed: int) -> RenderOptions:
        return RenderOptions(noise_sigma=self.noise_sigma, blur_sigma_px=self.blur_sigma_px, seed=seed)

    def _expose(self, radiance, seed: int) -> tuple[np.ndarray, np.ndarray]:
        return self.tissue.expose(radiance, self._options(seed))

    def _key(self, index: int) -> tuple[int, int]:
        """Frames rendered once share a key: (node, 0) while resting, (-1, frame in the tour) moving."""
        resting = self.resting_node(index)
        return (resting, 0) if resting is not None else (-1, index % self.cycle)

