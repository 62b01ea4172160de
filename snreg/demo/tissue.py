"""Tissue fixed in the trocar frame, seen by a camera that slides and turns about the pivot, with the probe in view.

Why: the camera's insertion is tracked from how the tissue moves in the stereo video (:mod:`snreg.odometry`); its
tests, its accuracy experiment and the surgery demo need rendered pairs of the thesis' rig whose truth is known.
The tissue is a height field ahead of the pivot (docs/design.md (Conventions): trocar frame: z along the shaft into the patient in
the reference pose): a shallow bowl whose rim rises towards the camera, tilted, with smooth bumps of a few mm, the
tissue texture of :mod:`snreg.demo.renderer` on it, lit by the endoscope's light. Each ray of each eye is cast
onto it by Newton steps on the height (a coarse cast first, then refined at every pixel: issue 36); the probe
(a :class:`~snreg.demo.renderer.ProbePose` in the camera frame) is drawn in front by
:class:`~snreg.demo.renderer.StereoRenderer`, which also adds the sensor noise and blur.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from snreg.camera import StereoCalibration
from snreg.demo.renderer import TEXTURE_MM, TEXTURE_PX, ProbePose, RenderOptions, StereoRenderer
from snreg.probe import ProbeModel

__all__ = ["TissueSurface", "TissueScene"]

_GRID_MM = 0.5            # height field spacing
_GRID_HALF_MM = 220.0     # the height field covers +-this about the trocar axis
_NEWTON_STEPS = 6         # at most, from the first guess (4-5 from the plane, 1-2 from the coarse cast)
_COARSE_PX = 5            # the ray cast's first guess: every this many pixels, then refined at every pixel
_CONVERGED_MM = 0.01      # a cast's Newton steps stop once none moved a distance further (the next would move <1e-3)


@dataclass(frozen=True)
class TissueSurface:
    """The tissue in the trocar frame, mm and degrees: ``depth_mm`` from the pivot along z where the axis meets it,
    a bowl of ``bowl_radius_mm`` (its rim nearer the camera), tilted ``tilt_deg`` (about y, about x), with bumps of
    sd ``relief_mm`` and size ``relief_scale_mm``; ``seed`` places the bumps, ``texture_seed`` draws the texture.
    ``anchors`` ((x, y, z) points, mm): the surface passes through each, raised to it (or lowered) by a round mound of
    sd ``anchor_radius_mm`` (the demo's sentinel nodes: the probe rests on their tops)."""

    depth_mm: float = 240.0
    bowl_radius_mm: float = 260.0
    tilt_deg: tuple[float, float] = (8.0, -5.0)
    relief_mm: float = 3.0
    relief_scale_mm: float = 8.0
    seed: int = 0
    texture_seed: int = 7
    anchors: tuple[tuple[float, float, float], ...] = ()
    anchor_radius_mm: float = 10.0

    def heights(self) -> np.ndarray:
        """(n, n, 3) float32 grid over +-``_GRID_HALF_MM`` in x and y: the surface's z and its slopes dz/dx, dz/dy."""
        n = int(round(2 * _GRID_HALF_MM / _GRID_MM)) + 1
        axis = np.linspace(-_GRID_HALF_MM, _GRID_HALF_MM, n)
        x, y = np.meshgrid(axis, axis)
        rng = np.random.default_rng([self.seed, 31])
        relief = np.zeros((n, n))
        for scale, weight in ((self.relief_scale_mm, 1.0), (3.0 * self.relief_scale_mm, 1.5)):
            field = cv2.GaussianBlur(rng.standard_normal((n, n)), (0, 0), scale / _GRID_MM)
            relief += weight * field / field.std()
        relief *= self.relief_mm / relief.std()
        slope_x, slope_y = np.tan(np.radians(self.tilt_deg))
        z = self.depth_mm + slope_x * x + slope_y * y - (x**2 + y**2) / (2.0 * self.bowl_radius_mm) + relief
        if self.anchors:
            z -= self._mounds(z, x, y)
        dz_dy, dz_dx = np.gradient(z, _GRID_MM)
        return np.dstack([z, dz_dx, dz_dy]).astype(np.float32)

    def _mounds(self, z: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(n, n) the mounds that bring the surface ``z`` (on the grid ``x``, ``y``) to every anchor: Gaussians of
        ``anchor_radius_mm`` whose heights solve for all anchors at once (they overlap)."""
        anchors = np.asarray(self.anchors, dtype=float).reshape(-1, 3)
        columns = (anchors[:, :2] + _GRID_HALF_MM) / _GRID_MM
        under = cv2.remap(z.astype(np.float32), columns[:, 0].astype(np.float32)[None],
                          columns[:, 1].astype(np.float32)[None], cv2.INTER_LINEAR)[0]
        apart = np.linalg.norm(anchors[:, None, :2] - anchors[None, :, :2], axis=-1)
        heights = np.linalg.solve(np.exp(-0.5 * (apart / self.anchor_radius_mm) ** 2), under - anchors[:, 2])
        mounds = np.zeros_like(z)
        for (ax, ay, _), height in zip(anchors, heights):
            mounds += height * np.exp(-0.5 * ((x - ax) ** 2 + (y - ay) ** 2) / self.anchor_radius_mm**2)
        return mounds


class TissueScene:
    """Render left/right BGR frames of the tissue from a camera pose in the trocar frame, with the probe in view.

    ``calibration``: the stereo cameras (the resolution to render); ``probe``: the probe model drawn;
    ``probe_in_front``: the tissue never hides the probe (a probe resting on a steep surface would dip into it).
    """

    def __init__(self, calibration: StereoCalibration, probe: ProbeModel, surface: TissueSurface = TissueSurface(),
                 *, probe_in_front: bool = False):
        self.surface, self.probe_in_front = surface, probe_in_front
        self.renderer = StereoRenderer(calibration, probe, texture_seed=surface.texture_seed)
        self._grid = surface.heights()
        self._texture = self.renderer.texture

    def render(self, trocar_from_camera: np.ndarray, probe: ProbePose | None = None,
               options: RenderOptions = RenderOptions()) -> tuple[np.ndarray, np.ndarray]:
        """Left and right BGR uint8 frames from the camera at ``trocar_from_camera`` (4, 4); ``probe`` in the left
        camera frame (None: tissue alone); ``options``: noise, blur and seed as for the probe renderer."""
        return self.expose(self.radiance(trocar_from_camera, probe, options), options)

    def expose(self, radiance: tuple[np.ndarray, np.ndarray], options: RenderOptions) -> tuple[np.ndarray, np.ndarray]:
        """Frames of :meth:`radiance`'s images: blur, sensor noise drawn by OpenCV under ``options.seed`` (a third of
        numpy's cost, :meth:`StereoRenderer.expose`) and 8-bit quantisation."""
        return self.renderer.expose(radiance, options, opencv_noise=True)

    def radiance(self, trocar_from_camera: np.ndarray, probe: ProbePose | None = None,
                 options: RenderOptions = RenderOptions()) -> tuple[np.ndarray, np.ndarray]:
        """The noise-free float images (:meth:`StereoRenderer.expose` makes frames of them)."""
        pose = np.asarray(trocar_from_camera, dtype=float)
        rotation, centre = pose[:3, :3].astype(np.float32), pose[:3, 3]
        ahead = self.surface.depth_mm - float(centre @ rotation[:, 2])

        def background(eye, rays, origin):
            return self._cast(cv2.transform(rays, rotation), (rotation @ origin + centre).astype(np.float32))

        return self.renderer.radiance_over(background, probe, options, exposure_mm=max(ahead, 20.0),
                                           probe_in_front=self.probe_in_front)

    def distance_ahead(self, trocar_from_camera: np.ndarray) -> np.ndarray:
        """(H, W) distance (mm) along each left-eye ray from the camera to the tissue: the depth truth."""
        pose = np.asarray(trocar_from_camera, dtype=float)
        rays, _ = self.renderer.eye_rays(0)
        depth, _, _ = self._cast(cv2.transform(rays, pose[:3, :3].astype(np.float32)), pose[:3, 3].astype(np.float32))
        return depth

    def _cast(self, rays: np.ndarray, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Distance along each ray (trocar frame) to the surface, the texture colour there and its Lambert term under
        the light at the camera (:meth:`StereoRenderer.radiance_over` lights the colour with it in one product).

        Newton steps on the height from the plane at ``depth_mm``, first on every :data:`_COARSE_PX`-th ray, then at
        every pixel from that guess resized to full size, each step only on the rays the last one still moved by
        :data:`_CONVERGED_MM` or more (one step at every pixel, then a few percent: a third of six steps from the
        plane at every pixel); the distances are those, converged to float32 precision (the surface is a smooth
        height field: one intersection per ray)."""
        r_x, r_y, ray_z = cv2.split(np.ascontiguousarray(rays, dtype=np.float32))
        grazing = np.abs(ray_z).min() < 1e-3
        r_z = np.where(np.abs(ray_z) < 1e-3, np.float32(1e-3), ray_z) if grazing else ray_z
        step = _COARSE_PX
        first = slice(step // 2, None, step)
        coarse = tuple(np.ascontiguousarray(r[first, first]) for r in (r_x, r_y, r_z))
        t, _, _ = self._newton(coarse, origin, (self.surface.depth_mm - origin[2]) / coarse[2])
        height, width = r_x.shape
        t, h, along = self._newton((r_x, r_y, r_z), origin,
                                   cv2.resize(t, (width, height), interpolation=cv2.INTER_LINEAR))
        slope_x, slope_y = h[:, 1].reshape(height, width), h[:, 2].reshape(height, width)
        if grazing:                                 # the surface's slopes along the ray as it truly runs
            along = ray_z - slope_x * r_x - slope_y * r_y
        lambert = np.abs(along) / np.sqrt(1.0 + slope_x**2 + slope_y**2)     # the normal is (-slope_x, -slope_y, 1)
        texels = np.float32(TEXTURE_PX / TEXTURE_MM)
        colour = cv2.remap(self._texture, (origin[0] + t * r_x) * texels + np.float32(TEXTURE_PX / 2),
                           (origin[1] + t * r_y) * texels + np.float32(TEXTURE_PX / 2), cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REFLECT)
        t = np.where(t > 1.0, t, np.float32(np.inf))
        return t, colour, lambert

    def _newton(self, rays: tuple[np.ndarray, np.ndarray, np.ndarray], origin: np.ndarray, t: np.ndarray):
        """Newton steps on the height along rays (x, y, z components (h, w), z kept off 0) from distances ``t``
        (mm), each on the rays whose last step moved :data:`_CONVERGED_MM` or more, at most :data:`_NEWTON_STEPS`;
        returns the distances (h, w), and for each ray the surface's (z, dz/dx, dz/dy) (h * w, 3) and the ray's z
        less the surface's slopes along it (h, w) where its last step started (under a micrometre from the end)."""
        shape = t.shape
        r_x, r_y, r_z = (np.ravel(r) for r in rays)
        cells = np.float32(1.0 / _GRID_MM)             # the rays in height-field cells per mm
        c_x, c_y = r_x * cells, r_y * cells
        o_x, o_y = ((np.float32(v) + np.float32(_GRID_HALF_MM)) * cells for v in origin[:2])
        t = t.astype(np.float32).ravel()
        h, along, active = None, None, None
        for _ in range(_NEWTON_STEPS):
            if active is None:
                ray_x, ray_y, ray_z, at, map_x, map_y = r_x, r_y, r_z, t, c_x, c_y
            else:
                ray_x, ray_y, ray_z, at, map_x, map_y = (a[active] for a in (r_x, r_y, r_z, t, c_x, c_y))
            under = self._heights_under(at * map_x + o_x, at * map_y + o_y, shape[1])
            slopes = ray_z - under[:, 1] * ray_x - under[:, 2] * ray_y
            change = (origin[2] + at * ray_z - under[:, 0]) / np.where(np.abs(slopes) < 0.05, np.float32(0.05), slopes)
            if active is None:
                h, along, t = under, slopes, at - change
                moving = np.flatnonzero(np.abs(change) >= _CONVERGED_MM)
            else:
                h[active], along[active], t[active] = under, slopes, at - change
                moving = active[np.abs(change) >= _CONVERGED_MM]
            if moving.size == 0:
                break
            active = moving
        return t.reshape(shape), h, along.reshape(shape)

    def _heights_under(self, map_x: np.ndarray, map_y: np.ndarray, width: int) -> np.ndarray:
        """(n, 3) the surface's (z, dz/dx, dz/dy) at height-field cells (``map_x``, ``map_y``) (n,), looked up in
        rows of ``width`` (OpenCV remaps fewer than 32767 columns)."""
        n = map_x.size
        rows = -(-n // width)
        if rows * width != n:
            map_x, map_y = (np.concatenate([m, np.zeros(rows * width - n, np.float32)]) for m in (map_x, map_y))
        under = cv2.remap(self._grid, map_x.reshape(rows, width), map_y.reshape(rows, width), cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REPLICATE)
        return under.reshape(-1, 3)[:n]
