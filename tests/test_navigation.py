"""Navigation on the endoscope's images: hot spots projected by hand through a known pose and a pinhole camera."""

import numpy as np
import pytest

from snreg import geometry
from snreg.camera import thesis_calibration
from snreg.registration.report import MissingNode
from snreg.tracking.stereo import StereoTracker
from snreg.workflow.navigation import (EDGE_MARGIN_FRACTION, edge_arrow, hot_spot_view, navigate,
                                       nearest_words, region_ellipse, trocar_from_camera_at, view_words)

FOCAL, SIZE = 1000.0, (1920, 1080)
CENTRE_PX = np.array([960.0, 540.0])
BASELINE = 5.0                      # the right eye 5 mm to the right of the left one


def pinhole(points, eye):
    points = np.asarray(points, float) - np.array([BASELINE * eye, 0.0, 0.0])
    return FOCAL * points[:, :2] / points[:, 2:] + CENTRE_PX


def spot(xyz, bound=10.0, name="P4"):
    return MissingNode(3, name, "OBT R", np.asarray(xyz, float), bound)


@pytest.fixture
def pose():
    """camera_from_trocar: the camera 100 mm along the trocar's z, turned 30 degrees about its axis, seeded."""
    rng = np.random.default_rng(7)
    turn = geometry.transform_from_euler(30.0, 0.0, 0.0, [0.0, 0.0, 0.0])
    shift = geometry.make_transform(np.eye(3), rng.normal(0.0, 5.0, 3) + [0.0, 0.0, -100.0])
    return shift @ turn


def test_a_hot_spot_in_view_is_drawn_where_the_pose_and_the_camera_put_it_in_each_eye(pose):
    camera_point = np.array([20.0, -30.0, 150.0])
    trocar_point = geometry.apply(geometry.invert(pose), camera_point[None])[0]
    view = hot_spot_view(spot(trocar_point), pose, pinhole, SIZE)
    np.testing.assert_allclose(view.camera_xyz, camera_point, atol=1e-9)
    left, right = view.eyes
    np.testing.assert_allclose(left.pixel, CENTRE_PX + FOCAL * np.array([20.0, -30.0]) / 150.0, atol=1e-6)
    np.testing.assert_allclose(right.pixel, CENTRE_PX + FOCAL * np.array([15.0, -30.0]) / 150.0, atol=1e-6)
    assert left.arrow is None and right.arrow is None and left.on_screen
    # the 10 mm sphere at 150 mm: about 67 px across the line of sight; the radial axis is the larger (oblique view)
    assert left.ellipse.axes[1] == pytest.approx(FOCAL * 10.0 / 150.0, rel=0.01)
    assert left.ellipse.axes[0] > left.ellipse.axes[1]
    radial = np.degrees(np.arctan2(-30.0, 20.0)) % 180
    assert min(abs(left.ellipse.angle_deg % 180 - radial), 180 - abs(left.ellipse.angle_deg % 180 - radial)) < 1.0
    assert view.distance_mm is None and view_words(view) == "P4: no probe fix"


def test_the_ellipse_is_the_linear_image_of_the_sphere_through_the_real_projection():
    tracker = StereoTracker(thesis_calibration())
    centre = np.array([-15.0, 10.0, 120.0])
    ellipse = region_ellipse(centre, 8.0, tracker.project, 0)
    fx = thesis_calibration().K1[0, 0]
    np.testing.assert_allclose(ellipse.centre, tracker.project(centre[None], 0)[0])
    assert ellipse.axes[1] == pytest.approx(fx * 8.0 / 120.0, rel=0.02)
    # points on the sphere's rim seen across the line of sight land on the ellipse's boundary, within 2 %
    across = np.cross(centre, [0.0, 1.0, 0.0])
    rim = centre + 8.0 * across / np.linalg.norm(across)
    distance = np.linalg.norm(tracker.project(rim[None], 0)[0] - ellipse.centre)
    assert ellipse.axes[1] * 0.98 <= distance <= ellipse.axes[0] * 1.02


def test_a_hot_spot_off_screen_gets_an_arrow_at_the_border_pointing_its_way(pose):
    off_right = geometry.apply(geometry.invert(pose), np.array([[300.0, 0.0, 100.0]]))[0]
    mark = hot_spot_view(spot(off_right), pose, pinhole, SIZE).eyes[0]
    assert mark.pixel is None and mark.ellipse is None
    margin = EDGE_MARGIN_FRACTION * 1080
    np.testing.assert_allclose(mark.arrow.direction, [1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(mark.arrow.position, [1920 - margin, 540.0], atol=1e-6)
    behind = geometry.apply(geometry.invert(pose), np.array([[0.0, -50.0, -40.0]]))[0]
    up = hot_spot_view(spot(behind), pose, pinhole, SIZE).eyes[1]
    assert up.pixel is None
    np.testing.assert_allclose(up.arrow.direction, [0.0, -1.0], atol=1e-9)
    np.testing.assert_allclose(up.arrow.position, [960.0, margin], atol=1e-6)
    corner = edge_arrow(np.array([960.0 - margin, 540.0 - margin]), SIZE)    # towards the inset lower right corner
    np.testing.assert_allclose(corner.position, [1920 - margin, 1080 - margin], atol=1e-6)
    steep = edge_arrow(np.array([960.0, 1080.0]), SIZE)            # steeper than the corner: meets the bottom edge
    assert steep.position[1] == pytest.approx(1080 - margin) and steep.position[0] < 1920 - margin


def test_the_way_from_the_tip_is_said_in_the_view_with_its_depth(pose):
    to_trocar = geometry.invert(pose)
    tip_camera = np.array([0.0, 0.0, 100.0])
    target_camera = tip_camera + np.array([-30.0, -35.0, 12.0])     # left, up and 12 mm deeper: 47.6 mm
    target = spot(geometry.apply(to_trocar, target_camera[None])[0], bound=8.0)
    view = hot_spot_view(target, pose, pinhole, SIZE, geometry.apply(to_trocar, tip_camera[None])[0])
    assert view.deeper_mm == pytest.approx(12.0) and view.distance_mm == pytest.approx(47.63, abs=0.01)
    assert view_words(view) == "P4: 48 mm, up and left on screen, 12 mm deeper"
    nearer = hot_spot_view(target, pose, pinhole, SIZE,
                           geometry.apply(to_trocar, (target_camera + [0.0, 0.0, 30.0])[None])[0])
    assert view_words(nearer) == "P4: 30 mm, 30 mm nearer"
    inside = hot_spot_view(target, pose, pinhole, SIZE,
                           geometry.apply(to_trocar, (target_camera + [3.0, 0.0, 0.0])[None])[0])
    assert inside.inside and view_words(inside) == "the tip is inside P4's 90 % region"


def test_the_words_name_the_hot_spot_nearest_the_tip(pose):
    to_trocar = geometry.invert(pose)
    near, far = (spot(geometry.apply(to_trocar, np.array([[0.0, d, 100.0]]))[0], name=n)
                 for d, n in ((20.0, "P2"), (60.0, "P3")))
    tip = geometry.apply(to_trocar, np.array([[0.0, 0.0, 100.0]]))[0]
    views = navigate([far, near], pose, pinhole, SIZE, tip)
    assert [v.target.preop_id for v in views] == ["P3", "P2"]
    assert nearest_words(views) == "P2: 20 mm, down on screen, at the tip's depth"
    assert nearest_words([]) == ""


def test_the_camera_pose_is_the_chain_at_the_frames_insertion_and_orientation():
    from snreg.chain import trocar_from_camera
    from snreg.demo.surgery_scene import surgery_demo_chain

    chain = surgery_demo_chain()
    orientation = geometry.rotation_from_euler(10.0, 20.0, -5.0)
    np.testing.assert_allclose(trocar_from_camera_at(chain, orientation), trocar_from_camera(chain, orientation))

    slid = chain.with_insertion(float(np.linalg.norm(chain.imu_from_camera[:3, 3])) - chain.imu_trocar_mm + 15.0)
    step = type("Step", (), {"chain": slid})()          # an InsertionStep's chain at the frame's insertion
    moved = trocar_from_camera_at(chain, orientation, step)
    np.testing.assert_allclose(moved, trocar_from_camera(slid, orientation))
    assert not np.allclose(moved[:3, 3], trocar_from_camera_at(chain, orientation)[:3, 3])
