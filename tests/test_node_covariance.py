"""Each node's own error (issue 28): the covariance's shape against the geometry (the stereo ray, the tip's lever along
the stripes, the probe's prior, the IMU at the node's lever about the pivot), checked against sampled errors, and the
90 % ellipsoid test."""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration
from snreg.demo.scene import PROBE_AXIS
from snreg.probe import default_probe_model
from snreg.tracking.uncertainty import (NodeUncertainty, inside_ellipsoid, node_covariance, node_covariance_parts,
                                        orientation_covariance, pointing_covariance, tip_covariance,
                                        triangulation_covariance)

CAMERAS = thesis_calibration()
PROBE = default_probe_model()
REFERENCE = ChainCalibration.manual().with_reference(np.eye(3))      # the trocar axes set with the IMU level


def _eigen(covariance):
    values, vectors = np.linalg.eigh(covariance)
    return np.sqrt(np.maximum(values, 0.0)), vectors


@pytest.mark.parametrize("depth", [60.0, 100.0, 150.0])
def test_a_triangulated_point_errs_along_its_viewing_ray_by_twice_depth_over_baseline(depth):
    point = np.array([10.0, -5.0, depth])
    sd, axes = _eigen(triangulation_covariance(CAMERAS, point, 0.3))
    ray = point / np.linalg.norm(point)
    assert np.degrees(np.arccos(abs(axes[:, 2] @ ray))) < 2.5          # the longest axis: the ray (from the baseline)
    # the disparity carries the depth (two x measurements), both eyes average the lateral position: 2 Z / b
    np.testing.assert_allclose(sd[2] / sd[:2], 2 * depth / CAMERAS.baseline_mm, rtol=0.03)
    np.testing.assert_allclose(sd[:2], depth * 0.3 / CAMERAS.P1[0, 0] / np.sqrt(2), rtol=0.03)


def test_the_first_order_covariance_is_what_noisy_pixels_triangulate_to():
    rng = np.random.default_rng(3)
    point = np.array([-15.0, 8.0, 90.0])
    rectified = CAMERAS.R1 @ point
    pixels = [P[:, :3] @ rectified + P[:, 3] for P in (CAMERAS.P1, CAMERAS.P2)]
    pixels = [(h[:2] / h[2])[:, None] + rng.normal(0.0, 0.5, (2, 4000)) for h in pixels]
    homogeneous = cv2.triangulatePoints(CAMERAS.P1, CAMERAS.P2, pixels[0], pixels[1])
    sampled = (CAMERAS.R1.T @ (homogeneous[:3] / homogeneous[3])).T
    np.testing.assert_allclose(np.cov(sampled, rowvar=False), triangulation_covariance(CAMERAS, point, 0.5),
                               rtol=0.1, atol=2e-4)


def test_the_tip_inherits_the_ray_and_the_stripes_lever_across_the_probe():
    point = np.array([10.0, -5.0, 100.0])
    ray = point / np.linalg.norm(point)
    side = np.cross(ray, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)                   # a probe seen from the side: its axis across the ray
    sd, axes = _eigen(tip_covariance(CAMERAS, PROBE, point, side, 0.3))
    along = np.sqrt(ray @ triangulation_covariance(CAMERAS, point, 0.3) @ ray)
    assert abs(axes[:, 2] @ ray) > 0.999
    # stripes at 20, 30, 40 mm: their mean (1/3 of a point's variance) and the tip 30 mm out on a line 20 mm long
    # (2 x 1.5^2 = 4.5 of it), so sqrt(1/3 + 4.5) = 2.2 times one point's error
    assert sd[2] / along == pytest.approx(np.sqrt(1 / 3 + 4.5), rel=0.05)
    tilted = tip_covariance(CAMERAS, PROBE, point, PROBE_AXIS, 0.3)      # the phantom's probe: the ray across its axis
    across = ray - (ray @ PROBE_AXIS) * PROBE_AXIS
    assert abs(_eigen(tilted)[1][:, 2] @ across / np.linalg.norm(across)) > 0.99


def test_pointing_is_the_probes_prior_about_the_tip():
    covariance = pointing_covariance(PROBE_AXIS, 5.0, 6.0)
    assert PROBE_AXIS @ covariance @ PROBE_AXIS == pytest.approx(6.0**2 / 3)     # up to 6 mm ahead: mean offset kept
    assert np.trace(covariance) == pytest.approx(2 * 5.0**2 / 4 + 6.0**2 / 3)
    rng = np.random.default_rng(0)                 # the same second moments as the draws the budget makes
    radius, angle = 5.0 * np.sqrt(rng.uniform(0, 1, 20000)), rng.uniform(0, 2 * np.pi, 20000)
    e1 = np.cross(PROBE_AXIS, [0.0, 0.0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(PROBE_AXIS, e1)
    offsets = (radius * np.cos(angle))[:, None] * e1 + (radius * np.sin(angle))[:, None] * e2 \
        + rng.uniform(0, 6.0, 20000)[:, None] * PROBE_AXIS
    np.testing.assert_allclose(offsets.T @ offsets / len(offsets), covariance, atol=0.25)


def test_the_imu_term_grows_with_the_lever_and_with_the_turn_from_the_reference():
    lever = np.array([0.0, 0.0, 200.0])
    assert np.allclose(orientation_covariance(lever, 0.5) @ lever, 0.0)       # a turn about the lever moves nothing
    assert np.trace(orientation_covariance(2 * lever, 0.5)) == pytest.approx(4 * np.trace(
        orientation_covariance(lever, 0.5)))
    uncertainty = NodeUncertainty(trocar_camera_sd_mm=0.0, insertion_sd_mm=0.0)

    def imu_part(depth, turn_deg):
        turned = Rotation.from_euler("x", turn_deg, degrees=True).as_matrix()
        return node_covariance_parts(uncertainty, CAMERAS, PROBE, REFERENCE, turned, [0.0, 0.0, depth],
                                     PROBE_AXIS)["chain"]

    assert np.abs(imu_part(100.0, 0.0)).max() < 1e-12           # at the reference pose the trocar frame is the IMU's
    near, far = (_eigen(imu_part(depth, 10.0))[0][2] for depth in (60.0, 150.0))
    # 0.48 deg at the node's lever about the pivot: the trocar-camera distance plus the depth
    assert near == pytest.approx(np.radians(0.48) * (158.0 + 60.0), rel=0.02)
    assert far == pytest.approx(np.radians(0.48) * (158.0 + 150.0), rel=0.02)
    half = np.trace(imu_part(100.0, 0.5)) / np.trace(imu_part(100.0, 10.0))
    assert half == pytest.approx(0.25, rel=0.02)                  # below the smallest tested turn (1 deg): in proportion


def test_the_insertion_slides_the_node_along_the_shaft_and_a_tracked_one_brings_its_own_sd():
    quiet = NodeUncertainty(image_sd_px=0.0, residual_mm=0.0, pointing_lateral_mm=0.0, pointing_axial_mm=0.0,
                            imu_deg=0.0, trocar_camera_sd_mm=0.6, insertion_sd_mm=0.8)
    unseen = node_covariance(quiet, CAMERAS, PROBE, REFERENCE, np.eye(3), [5.0, 0.0, 90.0], PROBE_AXIS)
    shaft = REFERENCE.shaft_camera                                # along z at the reference pose
    np.testing.assert_allclose(unseen, (0.6**2 + 0.8**2) * np.outer(shaft, shaft), atol=1e-9)
    tracked = node_covariance(quiet, CAMERAS, PROBE, REFERENCE, np.eye(3), [5.0, 0.0, 90.0], PROBE_AXIS,
                              insertion_sd_mm=0.05)
    assert shaft @ tracked @ shaft == pytest.approx(0.6**2 + 0.05**2)


def test_the_window_adds_its_medians_spread_and_the_parts_turn_into_the_trocar_frame():
    turned = Rotation.from_euler("y", 20.0, degrees=True).as_matrix()
    tip = np.array([5.0, 0.0, 90.0])
    base = node_covariance_parts(NodeUncertainty(), CAMERAS, PROBE, REFERENCE, turned, tip, PROBE_AXIS)
    window = tip + np.random.default_rng(1).normal(0.0, [0.3, 0.3, 2.0], (60, 3))
    spread = node_covariance_parts(NodeUncertainty(), CAMERAS, PROBE, REFERENCE, turned, tip, PROBE_AXIS,
                                   window_camera=window)
    rotation = (REFERENCE.trocar_from_earth[:3, :3] @ turned @ REFERENCE.imu_from_camera[:3, :3])
    np.testing.assert_allclose(spread["tracking"] - base["tracking"],
                               rotation @ (np.pi / 2 * np.cov(window, rowvar=False) / 60) @ rotation.T, atol=1e-9)
    pointing = pointing_covariance(PROBE_AXIS, 5.0, 5.0)
    np.testing.assert_allclose(base["pointing"], rotation @ pointing @ rotation.T, atol=1e-9)
    total = node_covariance(NodeUncertainty(), CAMERAS, PROBE, REFERENCE, turned, tip, PROBE_AXIS)
    np.testing.assert_allclose(total, sum(base.values()), atol=1e-9)
    assert np.linalg.eigvalsh(total).min() > 0


def test_bad_magnitudes_and_axes_are_refused_in_one_sentence():
    with pytest.raises(ValueError, match="residual_mm"):
        NodeUncertainty(residual_mm=-1.0)
    with pytest.raises(ValueError, match="axis"):
        pointing_covariance([0.0, 0.0, 0.0], 5.0, 5.0)
    with pytest.raises(ValueError, match="behind"):
        triangulation_covariance(CAMERAS, [0.0, 0.0, -50.0], 0.3)


def test_ninety_percent_of_gaussian_errors_lie_inside_their_ellipsoid():
    rng = np.random.default_rng(7)
    covariances = np.array([triangulation_covariance(CAMERAS, [0.0, 0.0, z], 1.0) + np.eye(3)
                            for z in rng.uniform(60, 150, 4000)])
    offsets = np.einsum("nij,nj->ni", np.linalg.cholesky(covariances), rng.normal(size=(4000, 3)))
    assert inside_ellipsoid(offsets, covariances).mean() == pytest.approx(0.9, abs=0.015)
    assert not inside_ellipsoid([[0.0, 0.0, 10.0]], [np.eye(3)])[0]
