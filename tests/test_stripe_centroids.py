"""Where the stripe segmentation puts a stripe's centroid: on the band, whole, in both eyes alike."""

import numpy as np
import pytest

from snreg.camera import thesis_calibration
from snreg.demo.renderer import ProbePose, RenderOptions, StereoRenderer
from snreg.probe import default_probe_model
from snreg.tracking import StereoTracker
from snreg.tracking.markers import find_stripes

GREY, GREEN = (90, 90, 90), (70, 190, 60)         # the default probe's body-like background and its stripe colour


def _image(shapes) -> np.ndarray:
    image = np.full((240, 320, 3), GREY, np.uint8)
    for y0, y1, x0, x1 in shapes:
        image[y0:y1, x0:x1] = GREEN
    return image


def _centre(shapes) -> np.ndarray:
    """The pixel centroid (x, y) of the union of the rectangles (pixel centres at whole coordinates)."""
    mask = np.zeros((240, 320), bool)
    for y0, y1, x0, x1 in shapes:
        mask[y0:y1, x0:x1] = True
    return np.argwhere(mask)[:, ::-1].mean(axis=0)


def test_a_stripes_centroid_is_the_bands_not_a_pixel_right_and_down():
    bands = [(100, 140, 60 + 40 * k, 80 + 40 * k) for k in range(3)]
    stripes = find_stripes(_image(bands), default_probe_model())
    assert len(stripes) == 3
    for found, band in zip(stripes.centroids, bands):
        assert np.abs(found - _centre([band])).max() < 0.01, (found, _centre([band]))


def test_a_stripes_thin_edge_counts_though_the_opening_against_speckle_drops_it():
    # a band with a one-pixel-wide flank (a dim edge seen obliquely) and an isolated speck nearby
    band = [(100, 140, 100, 120), (100, 140, 120, 121), (139, 140, 121, 129)]
    image = _image(band)
    image[60, 60] = GREEN
    stripes = find_stripes(image, default_probe_model())
    assert len(stripes) == 1
    assert np.abs(stripes.centroids[0] - _centre(band)).max() < 0.01
    assert stripes.areas[0] == pytest.approx(sum((y1 - y0) * (x1 - x0) for y0, y1, x0, x1 in band))


def test_a_probe_fully_in_view_near_the_images_edge_is_tracked():
    # at 150 mm the tip 95 mm right of the axis: before, the opening shifted and thinned the dim stripes so that
    # the pair failed the spacing check ("stripes 6.8 mm apart where the probe's are 10 mm")
    calibration, probe = thesis_calibration(), default_probe_model()
    pose = ProbePose.make([95.0, 5.0, 150.0], [1.0, -0.35, 0.4])
    left, right = StereoRenderer(calibration, probe).render(pose, RenderOptions(noise_sigma=2.5, seed=1))
    fix = StereoTracker(calibration, probe).track(left, right)
    assert fix.n_stripes == 3
    assert np.linalg.norm(fix.tip - pose.tip) < 3.0
