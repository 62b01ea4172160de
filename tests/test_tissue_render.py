"""The surgery scene's renderer made cheaper (issue 36) renders the same scene: the tissue's depth as six Newton steps
from the plane at every pixel found it, the probe where the hit points of its cylinder and tip put it, and sensor
noise of the same statistics, seeded per frame."""

import threading

import cv2
import numpy as np
import pytest

from snreg.camera import thesis_calibration
from snreg.demo.renderer import ProbePose, RenderOptions, StereoRenderer
from snreg.demo.scene import Schedule
from snreg.demo.surgery_scene import SurgeryScene
from snreg.demo.tissue import _GRID_HALF_MM, _GRID_MM
from snreg.probe import default_probe_model


@pytest.fixture(scope="module")
def scene():
    """The surgery tour at a quarter of the thesis resolution; nothing rendered."""
    return SurgeryScene(thesis_calibration().scaled(0.25), default_probe_model(), Schedule(rest_frames=40))


def six_steps_from_the_plane(tissue, rays: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """(H, W) the slow reference: six Newton steps on the height at every pixel from the plane at the tissue's
    depth, float64."""
    grid = tissue._grid
    r = rays.reshape(-1, 3).astype(float)
    o = origin.astype(float)
    t = (tissue.surface.depth_mm - o[2]) / r[:, 2]

    def under(t):
        x, y = o[0] + t * r[:, 0], o[1] + t * r[:, 1]
        maps = [((v + _GRID_HALF_MM) / _GRID_MM).astype(np.float32).reshape(1, -1) for v in (x, y)]
        return np.concatenate([cv2.remap(grid, maps[0][:, k:k + 30000], maps[1][:, k:k + 30000], cv2.INTER_LINEAR,
                                         borderMode=cv2.BORDER_REPLICATE)[0] for k in range(0, t.size, 30000)])

    for _ in range(6):
        h = under(t)
        along = r[:, 2] - h[:, 1] * r[:, 0] - h[:, 2] * r[:, 1]
        t = t - (o[2] + t * r[:, 2] - h[:, 0]) / along
    return t.reshape(rays.shape[:2])


@pytest.mark.parametrize("index", [0, 520, 1500])
def test_the_tissue_depth_is_the_converged_newton_cast_at_every_pixel(scene, index):
    pose = scene.trocar_from_camera(index)
    rotation = pose[:3, :3].astype(np.float32)
    for eye in (0, 1):
        rays, origin = scene.tissue.renderer.eye_rays(eye)
        turned, start = cv2.transform(rays, rotation), (rotation @ origin + pose[:3, 3]).astype(np.float32)
        depth, _, lambert = scene.tissue._cast(turned, start)
        np.testing.assert_allclose(depth, six_steps_from_the_plane(scene.tissue, turned, start), atol=2e-3)
        assert 0.0 < lambert.min() and lambert.max() <= 1.0
    np.testing.assert_array_equal(scene.tissue.distance_ahead(pose), scene.tissue._cast(
        cv2.transform(scene.tissue.renderer.eye_rays(0)[0], rotation), pose[:3, 3].astype(np.float32))[0])


def probe_by_hit_points(renderer, eye: int, pose: ProbePose):
    """(H, W) depth (inf: no probe) and Lambert term of the probe over the whole image, the slow way: each hit point
    formed and its normal taken from the axis."""
    rays, origin = (a.astype(float) for a in renderer.eye_rays(eye))
    probe, r = renderer.probe, renderer.probe.radius_mm
    a, w = pose.tip, pose.axis
    delta = origin - a
    d_par = rays @ w
    d_perp = rays - d_par[..., None] * w
    delta_perp = delta - (delta @ w) * w
    qa, qb, qc = (d_perp**2).sum(-1), 2.0 * (d_perp @ delta_perp), delta_perp @ delta_perp - r * r
    disc = qb * qb - 4 * qa * qc
    with np.errstate(invalid="ignore", divide="ignore"):
        t_cyl = (-qb - np.sqrt(disc)) / (2 * qa)
        s = delta @ w + t_cyl * d_par
        b = rays @ delta
        disc_s = b * b - (delta @ delta - r * r)
        t_sph = -b - np.sqrt(disc_s)
        cyl = (disc > 0) & (t_cyl > 0) & (s >= 0) & (s <= probe.length_mm)
        sph = (disc_s > 0) & (t_sph > 0) & (delta @ w + t_sph * d_par < 0)
    t = np.where(cyl, t_cyl, np.where(sph, t_sph, np.inf))
    point = origin + np.where(np.isfinite(t), t, 0.0)[..., None] * rays
    axis_point = a + np.maximum((point - a) @ w, 0.0)[..., None] * w
    lambert = np.clip(-(((point - axis_point) / r) * rays).sum(-1), 0.0, 1.0)
    return t, lambert


def test_the_probe_is_drawn_where_its_hit_points_are(rng):
    calibration = thesis_calibration().scaled(0.25)
    renderer = StereoRenderer(calibration, default_probe_model())
    poses = [ProbePose.make(rng.uniform([-40, -20, 50], [40, 20, 150]), rng.normal(0, 1, 3) * [1, 1, 0.3] + [0, 0, 1])
             for _ in range(5)]
    poses += [ProbePose.make([-50.0, 0.0, 60.0], [-1.0, 0.2, 0.4]),      # cut by the image border
              ProbePose.make([0.0, 0.0, 8.0], [0.2, 0.1, 1.0])]          # its tip near the camera: the whole image cast
    for k, pose in enumerate(poses):
        for eye in (0, 1):
            rays = renderer.eye_rays(eye)[0]
            drawn = [np.full(rays.shape[:2], np.inf, np.float32), np.zeros(rays.shape, np.float32)]
            renderer._probe(eye, pose, RenderOptions(), *drawn, in_front=True)
            whole = [np.full(rays.shape[:2], np.inf, np.float32), np.zeros(rays.shape, np.float32)]
            renderer._probe(eye, pose, RenderOptions(), *whole, in_front=True, whole=True)
            np.testing.assert_array_equal(drawn[0], whole[0])             # the boxes round it miss none of it
            np.testing.assert_array_equal(drawn[1], whole[1])
            t, lambert = probe_by_hit_points(renderer, eye, pose)
            mask, reference = np.isfinite(drawn[0]), np.isfinite(t)
            assert reference.sum() > 100, k
            assert (mask != reference).sum() <= 3                         # grazing rays at the silhouette
            both = mask & reference
            np.testing.assert_allclose(drawn[0][both], t[both], atol=0.05)
            centre = [np.argwhere(m).mean(axis=0) for m in (mask, reference)]
            np.testing.assert_allclose(centre[0], centre[1], atol=0.05)
            # each pixel the stripes' or the body's colour, shaded by the reference's Lambert term
            albedo = drawn[1][both] / (0.25 + 0.75 * lambert[both])[:, None]
            off = np.min([np.abs(albedo - np.array(c, np.float32)).max(-1)
                          for c in (renderer.probe.stripe_bgr, renderer.probe.body_bgr)], axis=0)
            assert (off > 0.5).sum() <= 3
    aside = [np.full((270, 480), np.inf, np.float32), np.zeros((270, 480, 3), np.float32)]
    assert renderer._probe(0, ProbePose.make([-300.0, 0.0, 60.0], [-1.0, 0.0, 0.2]), RenderOptions(), *aside).size == 0
    assert np.isinf(aside[0]).all() and not aside[1].any()               # out of view: nothing drawn


def test_the_opencv_noise_has_sigma_and_is_seeded_per_frame():
    renderer = StereoRenderer(thesis_calibration().scaled(0.25), default_probe_model())
    flat = np.full((270, 480, 3), 100.0, np.float32)
    options = RenderOptions(noise_sigma=2.0, seed=12345)
    left, right = renderer.expose((flat, flat), options, opencv_noise=True)
    again = renderer.expose((flat, flat), options, opencv_noise=True)
    np.testing.assert_array_equal(left, again[0])
    np.testing.assert_array_equal(right, again[1])
    other = renderer.expose((flat, flat), RenderOptions(noise_sigma=2.0, seed=12346), opencv_noise=True)
    assert (other[0] != left).mean() > 0.5
    numpy_left, _ = renderer.expose((flat, flat), options)
    for frame in (left, right):
        values = frame.astype(float)
        # normal noise of sd 2 then truncated to whole grey levels, as numpy's path does: sd sqrt(4 + 1/12)
        assert values.std() == pytest.approx(np.sqrt(4.0 + 1.0 / 12.0), rel=0.02)
        assert values.mean() == pytest.approx(numpy_left.astype(float).mean(), abs=0.02)
        flat_values = values.reshape(-1) - values.mean()
        assert abs(np.corrcoef(flat_values[:-1], flat_values[1:])[0, 1]) < 0.01     # independent pixel to pixel
    assert abs(np.corrcoef(left.reshape(-1), right.reshape(-1))[0, 1]) < 0.01       # and eye to eye
    drawn = {}

    def expose(name):
        drawn[name] = [renderer.expose((flat, flat), RenderOptions(noise_sigma=2.0, seed=s), opencv_noise=True)
                       for s in range(6)]

    threads = [threading.Thread(target=expose, args=(name,)) for name in ("a", "b")]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for one, two in zip(drawn["a"], drawn["b"]):                       # the generators are each thread's own
        np.testing.assert_array_equal(one[0], two[0])


def test_a_surgery_frame_rendered_twice_is_the_same(scene):
    moving = scene.tour.rest_starts[1] - 10
    assert scene.resting_node(moving) is None
    first = scene._render_distinct(moving, scene._key(moving))
    second = scene._render_distinct(moving, scene._key(moving))
    for a, b in zip(first, second):
        np.testing.assert_array_equal(a, b)
    rest = scene.tour.rest_starts[2]
    exposures = [scene._render_distinct(rest, scene._key(rest)) for _ in range(2)]
    np.testing.assert_array_equal(exposures[0].lefts[3], exposures[1].lefts[3])
    assert (exposures[0].lefts[3] != exposures[0].lefts[4]).mean() > 0.5   # each exposure its own noise
