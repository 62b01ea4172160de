"""Label placement and camera fit of the node views, as plain functions (OpenGL need not render here)."""

import numpy as np

from snreg_gui.common.label_layout import MARKER_PX, fit_camera, label_boxes, place_beside, place_labels


def _overlap_area(a, b) -> float:
    return max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))


def test_clustered_labels_cover_no_label_and_no_marker():
    rng = np.random.default_rng(0)
    anchors = rng.normal(300.0, 4.0, (12, 2))                 # twelve nodes within a few pixels
    sizes = np.tile([34.0, 14.0], (12, 1))
    boxes = label_boxes(place_labels(anchors, sizes), sizes)
    markers = np.hstack([anchors - MARKER_PX, anchors + MARKER_PX])
    assert all(_overlap_area(boxes[a], boxes[b]) == 0 for a in range(12) for b in range(a + 1, 12))
    assert all(_overlap_area(box, marker) == 0 for box in boxes for marker in markers)
    assert np.array_equal(place_labels(anchors, sizes), place_labels(anchors, sizes))     # deterministic


def test_a_lone_label_sits_just_up_right_of_its_marker_and_stays_inside_the_area():
    corner = place_labels([[100.0, 100.0]], [[30.0, 12.0]])[0]
    assert 106.0 < corner[0] < 112.0 and 100.0 - 12.0 - 12.0 < corner[1] < 100.0 - 12.0 - 6.0
    corner = place_labels([[195.0, 5.0]], [[30.0, 12.0]], area=(200.0, 100.0))[0]    # top-right corner
    assert corner[0] >= 0 and corner[1] >= 0 and corner[0] + 30.0 <= 200.0


def test_a_label_beside_a_region_goes_right_of_it_unless_something_is_drawn_there():
    region, size = (100.0, 100.0, 140.0, 130.0), (60.0, 14.0)
    assert np.allclose(place_beside(region, size), [144.0, 108.0])            # right, centred on the region
    probe = [[140.0, 95.0, 220.0, 135.0]]                                    # the probe's marker and depth words
    corner = place_beside(region, size, probe)
    box = label_boxes(corner, size)[0]
    assert _overlap_area(box, probe[0]) == 0 and _overlap_area(box, region) == 0
    assert np.allclose(corner, [36.0, 108.0])                               # left of it, the next choice
    corner = place_beside(region, size, probe, area=(80.0, 0.0, 300.0, 300.0))   # no room on the left
    box = label_boxes(corner, size)[0]
    assert box[0] >= 80.0 and _overlap_area(box, probe[0]) == 0 and _overlap_area(box, region) == 0
    crowded = [[0.0, 0.0, 300.0, 300.0]]                                      # nowhere free: the least covered
    assert place_beside(region, size, crowded, area=(0.0, 0.0, 300.0, 300.0)) is not None


def test_camera_fit_keeps_a_far_node_in_view_from_any_direction():
    rng = np.random.default_rng(1)
    points = np.vstack([rng.normal([0.0, 0.0, 250.0], 5.0, (5, 3)), [[372.0, 0.0, 250.0]]])
    for width, height in ((800, 220), (800, 600), (300, 900)):
        centre, distance = fit_camera(points, fov_deg=60.0, width=width, height=height)
        half_h = np.radians(30.0)
        half_v = np.arctan(np.tan(half_h) * height / width)
        seen = np.arcsin(np.linalg.norm(points - centre, axis=1).max() / distance)   # worst case, any direction
        assert seen < min(half_h, half_v)
        assert np.allclose(centre, (points.min(axis=0) + points.max(axis=0)) / 2)


def test_a_label_inside_the_area_takes_the_first_free_spot_whatever_the_rounding():
    """Inside ``area`` a spot has no part outside, exactly: the area less the overlap once left rounding errors
    (1e-14 px^2), so the free spot right of the region was passed over for one whose error was smaller (left of it)
    and every spot was tried, each paint of each feed (issue 36: most of the GUI thread's time with hot spots shown)."""
    area = (0.0, 0.0, 470.0, 265.0)
    for x in np.linspace(100.3, 200.7, 30):
        for width in (81.0, 87.3, 95.5):
            corner = place_beside((x, 100.3, x + 20.0, 120.3), (width, 14.0), area=area)
            assert np.allclose(corner, [x + 20.0 + 4.0, 110.3 - 7.0])         # right of it, centred, 4 px apart
