"""Synthetic Firefly stereo pairs: a tissue-like scene with the DROP-IN probe at a known pose.

Ground truth for tests, the tracking accuracy experiment and the demo. Every pixel of
each eye is ray-cast in the left camera frame (mm; x right, y down, z forward): a
textured tissue plane behind the probe, the probe (a cylinder with a hemispherical tip,
stripes and body from the :class:`~snreg.probe.ProbeModel`), and an
optional tissue blob hiding part of one stripe. The endoscope light sits at the
camera (inverse-square fall-off, Lambert shading, optional specular highlights);
vignetting and a slow light gradient make the exposure uneven. Sensor noise and blur
are drawn from a seed, so a render is deterministic.

Distractors for the tracker, green things that are not the probe: round green fiducials on the
tissue, specular highlights on the tissue with a greenish colour fringe (both in 3D, so they match
in the two eyes), and greenish blobs cut by the image border.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from snreg.camera import StereoCalibration
from snreg.probe import ProbeModel

__all__ = ["ProbePose", "RenderOptions", "StereoRenderer"]

TEXTURE_MM = 600.0        # side of the tissue texture patch
TEXTURE_PX = 2048
_FIDUCIAL_BGR = np.array([70.0, 185.0, 75.0], np.float32)     # green: inside the probe model's stripe colour range
_FRINGE_BGR = np.array([90.0, 200.0, 110.0], np.float32)
_BORDER_BLOB_BGR = np.array([80.0, 170.0, 95.0], np.float32)
_BAND_PX = 16             # the probe is cast over boxes this many rows high round it (it lies across the image)


@dataclass(frozen=True)
class ProbePose:
    """The probe in the left camera frame: tip position (mm) and unit axis from the tip towards the body."""

    tip: np.ndarray
    axis: np.ndarray

    @classmethod
    def make(cls, tip, axis) -> "ProbePose":
        axis = np.asarray(axis, dtype=float)
        return cls(np.asarray(tip, dtype=float), axis / np.linalg.norm(axis))

    def point(self, s_mm: float) -> np.ndarray:
        """The axis point ``s_mm`` from the tip (e.g. the stripe-band centre)."""
        return self.tip + s_mm * self.axis


@dataclass(frozen=True)
class RenderOptions:
    """How to render a pair; the distractors (green things that are not the probe) are placed by ``seed``
    unless given."""

    noise_sigma: float = 0.0          # sensor noise, grey levels
    blur_sigma_px: float = 0.0
    specular: bool = False            # highlights on the probe
    hide_stripe: int | None = None    # index of a stripe partly hidden by a tissue blob
    background_gap_mm: float = 60.0   # tissue plane this far behind the probe tip
    seed: int = 0
    fiducials_mm: tuple[tuple[float, float], ...] = ()   # round green discs on the tissue at these (x, y), mm
    fiducial_diameter_mm: float = 6.0
    border_blobs: int = 0             # greenish blobs cut by the image border (a drape, a stained swab)
    highlights: int = 0               # specular highlights on the tissue: white spots with a greenish fringe
    probe: bool = True                # False: the scene without the probe (distractors alone)


def tissue_texture(seed: int) -> np.ndarray:
    """A BGR float32 texture: pink-red tissue with blotches, fine grain and darker vessels."""
    rng = np.random.default_rng(seed)
    size = TEXTURE_PX
    grain = np.zeros((size, size), np.float32)
    for octave, weight in ((4, 0.35), (16, 0.3), (64, 0.2), (256, 0.15)):
        small = rng.normal(0, 1, (octave, octave)).astype(np.float32)
        grain += weight * cv2.resize(small, (size, size), interpolation=cv2.INTER_CUBIC)
    fine = cv2.GaussianBlur(rng.normal(0, 1, (size, size)).astype(np.float32), (0, 0), 1.5)
    grain = grain / grain.std() * 0.5 + fine / fine.std() * 0.35
    vessels = np.zeros((size, size), np.float32)
    for _ in range(40):
        pts = np.cumsum(rng.normal(0, 25, (30, 2)), axis=0) + rng.uniform(0, size, 2)
        cv2.polylines(vessels, [pts.astype(np.int32)], False, 1.0, int(rng.integers(2, 7)), cv2.LINE_AA)
    vessels = cv2.GaussianBlur(vessels, (0, 0), 2.0)
    base = np.array([95.0, 105.0, 185.0], np.float32)          # BGR pink-red
    texture = base * (1.0 + 0.22 * grain[..., None]) - vessels[..., None] * np.array([40.0, 60.0, 70.0], np.float32)
    return np.clip(texture, 10, 255)


class StereoRenderer:
    """Render left/right BGR uint8 images of the probe scene for a stereo calibration."""

    def __init__(self, calibration: StereoCalibration, probe: ProbeModel, texture_seed: int = 7):
        self.calibration, self.probe = calibration, probe
        self.texture = tissue_texture(texture_seed)
        width, height = calibration.image_size
        u, v = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
        pixels = np.stack([u, v, np.ones_like(u)], axis=-1)
        rot = np.asarray(calibration.R, dtype=np.float32)
        self._eyes = []
        for K, D, to_left, origin in ((calibration.K1, calibration.D1, np.eye(3, dtype=np.float32), np.zeros(3)),
                                      (calibration.K2, calibration.D2, rot.T,
                                       -(calibration.R.T @ calibration.T.ravel()))):
            if np.any(np.asarray(D) != 0):       # each pixel's ray through the lens as calibrated
                normalised = cv2.undistortPoints(pixels[..., :2].reshape(-1, 1, 2).astype(np.float64), K, D)
                rays = np.dstack([normalised.reshape(height, width, 2), np.ones((height, width))]).astype(np.float32)
                rays = rays @ to_left.T
            else:
                rays = pixels @ np.linalg.inv(K).astype(np.float32).T @ to_left.T
            rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
            self._eyes.append((rays, origin.astype(np.float32)))
        radius = np.hypot((u - width / 2) / (width / 2), (v - height / 2) / (height / 2))
        self._vignette = (1.0 - 0.35 * radius**2).astype(np.float32)

    def eye_rays(self, eye: int) -> tuple[np.ndarray, np.ndarray]:
        """Unit rays (H, W, 3) of eye 0 (left) or 1 (right) through each pixel and their origin (3,), left camera frame."""
        return self._eyes[eye]

    def render(self, pose: ProbePose, options: RenderOptions = RenderOptions()) -> tuple[np.ndarray, np.ndarray]:
        """Left and right BGR uint8 images of the probe at ``pose``."""
        return self.expose(self.radiance(pose, options), options)

    def radiance(self, pose: ProbePose, options: RenderOptions = RenderOptions()) -> tuple[np.ndarray, np.ndarray]:
        """The noise-free float images; :meth:`expose` turns them into frames (for many noisy frames of one pose)."""
        images = tuple(self._shade(eye, pose, options) for eye in range(len(self._eyes)))
        if options.border_blobs:
            self._border_blobs(images, options)
        return images

    def radiance_over(self, background, pose: ProbePose | None, options: RenderOptions,
                      exposure_mm: float, *, probe_in_front: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free images of the probe at ``pose`` (None: no probe) in front of another scene.

        ``background(eye, rays, origin)`` gives, for eye 0 (left) or 1 (right), the distance along each ray (H, W),
        the unlit colour (H, W, 3) of that scene and a shade (H, W) its colour is still to be multiplied by (its
        Lambert term, so one product lights it; None: none), rays (H, W, 3) and origin (3,) in the left camera frame;
        the endoscope light is set for a scene ``exposure_mm`` ahead. ``probe_in_front``: the scene never hides the
        probe (drawn over it wherever the probe is, as if the scene gave way under it).
        """
        images = []
        for eye, (rays, origin) in enumerate(self._eyes):
            depth, colour, shade = background(eye, rays, origin)
            depth, colour = np.ascontiguousarray(depth, np.float32), np.ascontiguousarray(colour, np.float32)
            drawn = self._probe(eye, pose, options, depth, colour, in_front=probe_in_front) if pose is not None else []
            light = self._lighting(rays, depth, exposure_mm)
            if shade is not None:
                shade = np.array(shade, np.float32)
                shade.reshape(-1)[drawn] = 1.0         # the probe is shaded already
                light *= shade
            images.append(colour * light[..., None])
        return images[0], images[1]

    def expose(self, radiance: tuple[np.ndarray, np.ndarray], options: RenderOptions, *,
               opencv_noise: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Blur, sensor noise (seeded by ``options.seed``) and 8-bit quantisation of both eyes.

        ``opencv_noise``: draw the noise with OpenCV's generator (``cv2.randn``, its thread's generator seeded per eye
        from ``options.seed``): the same statistics (independent normal draws of sd ``noise_sigma`` at every pixel and
        channel) for a third of the CPU of numpy's; the tissue scenes use it (the surgery demo renders hundreds of
        frames), the probe-only scenes keep numpy's draws, which the tracking experiments' seeded figures were
        measured with."""
        rng = None if opencv_noise else np.random.default_rng(options.seed)
        eye_seeds = np.random.SeedSequence(options.seed).generate_state(2) >> 1 if opencv_noise else (0, 0)
        images = []
        for image, eye_seed in zip(radiance, eye_seeds):
            if options.blur_sigma_px > 0:
                image = cv2.GaussianBlur(image, (0, 0), options.blur_sigma_px)
            if options.noise_sigma > 0 and rng is None:
                noise = np.empty(image.shape, np.float32)
                cv2.setRNGSeed(int(eye_seed))           # OpenCV's generator is each thread's own: deterministic
                # less half a grey level: OpenCV's saturating conversion rounds where numpy's below truncates
                cv2.randn(noise.reshape(image.shape[0], -1), -0.5, float(options.noise_sigma))
                images.append(cv2.add(np.ascontiguousarray(image, np.float32), noise, dtype=cv2.CV_8U))
                continue
            if options.noise_sigma > 0:
                image = image + rng.standard_normal(image.shape, dtype=np.float32) * np.float32(options.noise_sigma)
            images.append(np.clip(image, 0, 255).astype(np.uint8))
        return images[0], images[1]

    # -- scene -------------------------------------------------------------
    def _shade(self, eye: int, pose: ProbePose, options: RenderOptions) -> np.ndarray:
        rays, origin = self._eyes[eye]
        depth = np.full(rays.shape[:2], np.inf, np.float32)
        colour = np.zeros(rays.shape, np.float32)
        self._tissue_plane(rays, origin, pose, options, depth, colour)
        if options.probe:
            self._probe(eye, pose, options, depth, colour)
        if options.hide_stripe is not None:
            self._blob(rays, origin, pose, options, depth, colour)
        return colour * self._lighting(rays, depth, pose.tip[2])[..., None]

    def _lighting(self, rays, depth, exposure_mm: float) -> np.ndarray:
        """(H, W) light at each pixel: the endoscope light at the camera (inverse-square fall-off, exposure set for
        ``exposure_mm``), vignetting and a slow gradient."""
        falloff = np.clip((1.15 * exposure_mm / np.where(np.isfinite(depth), depth, 1e4)) ** 2, 0.15, 1.6)
        gradient = 0.85 + 0.15 * np.linspace(-1, 1, rays.shape[1], dtype=np.float32)[None, :]
        return (falloff * self._vignette * gradient).astype(np.float32)

    def _tissue_plane(self, rays, origin, pose, options, depth, colour):
        z = pose.tip[2] + options.background_gap_mm
        normal = np.array([0.15, -0.1, -1.0], np.float32)
        normal /= np.linalg.norm(normal)
        anchor = np.array([0.0, 0.0, z], np.float32)
        t = ((anchor - origin) @ normal) / (rays @ normal)
        hit = origin + t[..., None] * rays
        scale = TEXTURE_PX / TEXTURE_MM
        map_x = (hit[..., 0] * scale + TEXTURE_PX / 2).astype(np.float32)
        map_y = (hit[..., 1] * scale + TEXTURE_PX / 2).astype(np.float32)
        tex = cv2.remap(self.texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        lambert = np.abs(rays @ normal)
        np.copyto(depth, t.astype(np.float32))
        np.copyto(colour, tex * lambert[..., None])
        if options.fiducials_mm or options.highlights:
            self._tissue_distractors(hit, z, options, colour)

    def _tissue_distractors(self, hit, plane_z: float, options: RenderOptions, colour) -> None:
        """Round green fiducials and specular highlights (white, with a greenish colour fringe) on the tissue."""
        for x, y in options.fiducials_mm:
            inside = np.hypot(hit[..., 0] - x, hit[..., 1] - y) <= options.fiducial_diameter_mm / 2.0
            colour[inside] = _FIDUCIAL_BGR * np.clip(colour[inside].mean(axis=-1, keepdims=True) / 120.0, 0.6, 1.2)
        if options.highlights:
            rng = np.random.default_rng((options.seed, 1))
            width, height = self.calibration.image_size
            span = plane_z * np.array([width, height]) / 2.0 / np.diag(self.calibration.K1)[:2]
            for centre in rng.uniform(-0.6, 0.6, (options.highlights, 2)) * span:
                r = np.hypot(hit[..., 0] - centre[0], hit[..., 1] - centre[1])
                ring = (r > 2.2) & (r < 3.2)
                colour[ring] = 0.2 * colour[ring] + 0.8 * _FRINGE_BGR
                colour += (250.0 * np.exp(-0.5 * (r / 1.2) ** 2))[..., None]

    def _border_blobs(self, images, options: RenderOptions) -> None:
        """Greenish discs centred on the image border (half of each cut off), at the same pixels in both eyes."""
        rng = np.random.default_rng((options.seed, 2))
        width, height = self.calibration.image_size
        for _ in range(options.border_blobs):
            side, along = int(rng.integers(4)), float(rng.uniform(0.15, 0.85))
            radius = int(round(rng.uniform(0.015, 0.03) * width))
            centre = [(int(along * width), 0), (width - 1, int(along * height)), (int(along * width), height - 1),
                      (0, int(along * height))][side]
            for image in images:
                cv2.circle(image, centre, radius, tuple(float(v) for v in _BORDER_BLOB_BGR), -1, cv2.LINE_AA)

    def _probe(self, eye: int, pose: ProbePose, options: RenderOptions, depth, colour, *, in_front: bool = False,
               whole: bool = False) -> np.ndarray:
        """Draw the probe into eye ``eye``'s ``depth`` and ``colour`` (H, W) where it is nearer than ``depth`` (or
        wherever it is, ``in_front``): cast only over the pixels that can see it (:meth:`_probe_windows`, a fifth of
        the image or less) unless ``whole``. Returns the flat indices of the pixels drawn."""
        rays, origin = self._eyes[eye]
        height, width = rays.shape[:2]
        windows = [(slice(0, height), slice(0, width))] if whole else self._probe_windows(eye, pose)
        pixels = np.concatenate([(np.arange(rows.start, rows.stop)[:, None] * width
                                  + np.arange(columns.start, columns.stop)).ravel() for rows, columns in windows]
                                or [np.zeros(0, int)])
        if pixels.size == 0:                            # out of view
            return pixels
        t, along, lambert = self._probe_cast(rays.reshape(-1, 3)[pixels], origin, pose)
        depth, colour = depth.reshape(-1), colour.reshape(-1, 3)       # views (both C-contiguous): drawn in place
        hit = np.isfinite(t) if in_front else t < depth[pixels]
        drawn = pixels[hit]
        depth[drawn] = t[hit]
        albedo = np.array([self.probe.body_bgr, self.probe.stripe_bgr], np.float32)[
            (self.probe.stripe_at(along[hit]) >= 0).astype(np.intp)]
        shade = albedo * (0.25 + 0.75 * lambert[hit][:, None])
        if options.specular:
            shade += 160.0 * (lambert[hit] ** 60)[:, None]
        colour[drawn] = shade
        return drawn

    def _probe_windows(self, eye: int, pose: ProbePose) -> list[tuple[slice, slice]]:
        """(rows, columns) boxes of eye ``eye`` that hold every pixel that can see the probe at ``pose``, one per band
        of :data:`_BAND_PX` rows it crosses: round the axis' projection (from a radius before the tip to the body's
        end, every 1/3 mm or so), 1.5 times the widest a sphere of its radius there can look and 4 pixels; the whole
        image when part of it is within two radii of the eye's image plane."""
        calibration, probe = self.calibration, self.probe
        radius = probe.radius_mm
        points = pose.tip + np.linspace(-radius, probe.length_mm, 256)[:, None] * pose.axis
        if eye == 0:
            K, D = np.asarray(calibration.K1, float), np.asarray(calibration.D1, float)
        else:
            K, D = np.asarray(calibration.K2, float), np.asarray(calibration.D2, float)
            points = points @ np.asarray(calibration.R, float).T + np.asarray(calibration.T, float).ravel()
        depth = points[:, 2]
        width, height = calibration.image_size
        if depth.min() < 2.0 * radius + 1.0:
            return [(slice(0, height), slice(0, width))]
        u, v = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, D)[0].reshape(-1, 2).T
        off_axis = np.hypot(points[:, 0], points[:, 1]) / depth       # a sphere looks longer off the axis
        margin = 1.5 * max(K[0, 0], K[1, 1]) * radius * np.sqrt(1.0 + off_axis**2) / depth + 4.0
        windows = []
        for top in range(0, height, _BAND_PX):
            near = (v + margin >= top) & (v - margin < top + _BAND_PX)
            if near.any():
                left = max(int(np.floor((u - margin)[near].min())), 0)
                right = min(int(np.ceil((u + margin)[near].max())) + 1, width)
                if left < right:
                    windows.append((slice(top, min(top + _BAND_PX, height)), slice(left, right)))
        return windows

    def _probe_cast(self, rays: np.ndarray, origin: np.ndarray, pose: ProbePose):
        """Cast unit ``rays`` (N, 3) from ``origin`` at the probe (a cylinder of its radius from the tip to its length,
        a hemisphere before the tip): (N,) the distance to it (inf where missed), the hit's axial position from the
        tip (mm) and the Lambert term of the light at the camera there. Each surface's Lambert term is the square root
        of its intersection's discriminant over the radius, so no hit point needs forming."""
        probe, r = self.probe, self.probe.radius_mm
        a, w = pose.tip.astype(np.float32), pose.axis.astype(np.float32)
        delta = origin - a
        along = float(delta @ w)
        delta_perp = delta - along * w
        d_par, half_b, b = (p.ravel() for p in cv2.split(cv2.transform(rays.reshape(-1, 1, 3),
                                                                        np.stack([w, delta_perp, delta]))))
        qa = 1.0 - d_par * d_par                       # the rays' length across the axis, squared
        disc = half_b * half_b - qa * (float(delta_perp @ delta_perp) - r * r)
        disc_s = b * b - (float(delta @ delta) - r * r)
        with np.errstate(invalid="ignore", divide="ignore"):
            t_cyl = (-half_b - np.sqrt(disc)) / qa
            t_sph = -b - np.sqrt(disc_s)
            s_cyl, s_sph = along + t_cyl * d_par, along + t_sph * d_par
            cyl = (disc > 0) & (t_cyl > 0) & (s_cyl >= 0) & (s_cyl <= probe.length_mm)
            sph = (disc_s > 0) & (t_sph > 0) & (s_sph < 0)      # the hemispherical tip where not the cylinder
            t = np.where(cyl, t_cyl, np.where(sph, t_sph, np.float32(np.inf)))
            lambert = np.clip(np.sqrt(np.where(cyl, disc, disc_s)) / r, 0.0, 1.0)
        return t, np.where(cyl, s_cyl, s_sph), lambert

    def _blob(self, rays, origin, pose, options, depth, colour):
        """A tissue sphere in front of one side of a stripe, hiding part of it."""
        probe = self.probe
        centre_axis = pose.point(probe.stripe_centres_mm[options.hide_stripe])
        to_camera = -centre_axis / np.linalg.norm(centre_axis)
        side = np.cross(pose.axis, to_camera)
        side /= np.linalg.norm(side)
        radius = probe.stripe_width_mm * 0.9
        centre = (centre_axis + to_camera * (probe.radius_mm + radius + 3.0)
                  + side * 0.6 * probe.radius_mm + pose.axis * probe.stripe_width_mm * 0.6).astype(np.float32)
        delta = origin - centre
        b = rays @ delta
        disc = b * b - (float(delta @ delta) - radius * radius)
        with np.errstate(invalid="ignore"):
            t = -b - np.sqrt(disc)
        hit = (disc > 0) & (t > 0) & (t < depth)
        depth[hit] = t[hit]
        normal = (origin + t[hit][:, None] * rays[hit] - centre) / radius
        lambert = np.clip(-(normal * rays[hit]).sum(-1), 0.0, 1.0)
        colour[hit] = np.array([85.0, 95.0, 170.0], np.float32) * (0.3 + 0.7 * lambert[:, None])
