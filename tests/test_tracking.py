"""Probe tracking on rendered stereo pairs against the rendered ground truth."""

import json

import cv2
import numpy as np
import pytest

from snreg.camera import THESIS_CALIBRATION_PATH, thesis_calibration
from snreg.cli import main
from snreg.demo.renderer import ProbePose, RenderOptions, StereoRenderer
from snreg.probe import default_probe_model, load_probe_model, save_probe_model
from snreg.simulation.tracking import run_tracking_experiment
from snreg.tracking import FixFilter, StereoTracker, TrackingError, summarise

AXIS = np.array([1.0, -0.35, 0.4])


@pytest.fixture(scope="module")
def scene():
    calibration, probe = thesis_calibration(), default_probe_model()
    return calibration, probe, StereoRenderer(calibration, probe)


def pose_at(depth, x=-25.0, axis=AXIS):
    return ProbePose.make([x, 5.0, depth], axis)


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip(abs(np.dot(a, b)) / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))


def test_probe_model_file_round_trip_and_errors(tmp_path):
    probe = default_probe_model()
    assert probe.diameter_mm == 10.0 and probe.stripe_centres_mm == (20.0, 30.0, 40.0) and probe.stripe_width_mm == 4.0
    save_probe_model(probe, tmp_path / "p.yaml")
    assert load_probe_model(tmp_path / "p.yaml") == probe
    (tmp_path / "bad.yaml").write_text("%YAML:1.0\n---\ndiameter_mm: 10.\n")
    with pytest.raises(ValueError, match="lacks length_mm"):
        load_probe_model(tmp_path / "bad.yaml")
    with pytest.raises(ValueError, match="no such probe model"):
        load_probe_model(tmp_path / "missing.yaml")


def test_renderer_is_deterministic_and_stereo_consistent(scene):
    _, _, renderer = scene
    a = renderer.render(pose_at(120), RenderOptions(noise_sigma=3, seed=5))
    b = renderer.render(pose_at(120), RenderOptions(noise_sigma=3, seed=5))
    c = renderer.render(pose_at(120), RenderOptions(noise_sigma=3, seed=6))
    assert a[0].shape == (1080, 1920, 3) and a[0].dtype == np.uint8
    np.testing.assert_array_equal(a[0], b[0])
    assert np.any(a[0] != c[0])
    green = [np.argwhere(cv2.inRange(cv2.cvtColor(img, cv2.COLOR_BGR2HSV), (40, 80, 40), (85, 255, 255)))[:, 1].mean()
             for img in a]
    expected = 1070.62 * 4.3015 / 130.0   # disparity of the probe ~130 mm away
    assert 0.7 * expected < green[0] - green[1] < 1.3 * expected


@pytest.mark.parametrize("depth", [80.0, 170.0, 270.0])
def test_stereo_trackers_recover_the_rendered_probe(scene, depth):
    calibration, probe, renderer = scene
    pose = pose_at(depth)
    left, right = renderer.render(pose, RenderOptions(noise_sigma=3, seed=1))
    fix = StereoTracker(calibration, probe, method="triangulation").track(left, right)
    assert np.linalg.norm(fix.centre - pose.point(probe.band_centre_mm)) < 1.0
    assert np.linalg.norm(fix.tip - pose.tip) < 3.0
    assert angle_deg(fix.axis, pose.axis) < 4.0 and np.dot(fix.axis, pose.axis) > 0
    assert fix.n_stripes == 3 and fix.quality > 0.8
    sgbm = StereoTracker(calibration, probe, method="sgbm").track(left, right)
    assert np.linalg.norm(sgbm.centre - pose.point(probe.band_centre_mm)) < 3.5


def test_partly_hidden_stripe_blur_and_highlights(scene):
    calibration, probe, renderer = scene
    pose = pose_at(120)
    left, right = renderer.render(pose, RenderOptions(noise_sigma=4, blur_sigma_px=1.2, specular=True, hide_stripe=1, seed=2))
    fix = StereoTracker(calibration, probe).track(left, right)
    assert np.linalg.norm(fix.centre - pose.point(probe.band_centre_mm)) < 3.0


def test_marker_width_baseline(scene):
    calibration, probe, renderer = scene
    pose = pose_at(150)
    left, _ = renderer.render(pose, RenderOptions(noise_sigma=3, seed=3))
    fix = StereoTracker(calibration, probe).marker_width(left)
    assert fix.method == "width" and np.linalg.norm(fix.centre - pose.point(probe.band_centre_mm)) < 10.0


def test_bad_input_gives_a_clear_tracking_error(scene):
    calibration, probe, renderer = scene
    tracker = StereoTracker(calibration, probe)
    away = renderer.render(ProbePose.make([0.0, 0.0, -200.0], AXIS))       # probe behind the camera
    with pytest.raises(TrackingError, match="no probe stripe found in the left image"):
        tracker.track(*away)
    left, right = renderer.render(pose_at(150))
    with pytest.raises(TrackingError, match="no probe stripe found in the right image"):
        tracker.track(left, away[1])
    with pytest.raises(TrackingError, match="640x480 but the calibration is for 1920x1080"):
        tracker.track(left, cv2.resize(right, (640, 480)))
    with pytest.raises(TrackingError, match="colour"):
        tracker.track(left, None)


def test_fix_filter_rejects_outliers_and_detects_stillness():
    rng = np.random.default_rng(0)
    flt = FixFilter(window=5, outlier_mm=5.0, reset_after=3, still_frames=10, still_mm=1.0)
    states = [flt.push(np.array([10.0, 0, 100]) + rng.normal(0, 0.2, 3)) for _ in range(12)]
    assert states[-1].still and states[-1].spread_mm < 1.0
    jump = flt.push(np.array([30.0, 0, 100]))
    assert not jump.accepted and np.linalg.norm(jump.smoothed - [10, 0, 100]) < 1.0
    for _ in range(3):
        state = flt.push(np.array([30.0, 0, 100]))
    assert state.accepted and not state.still
    assert flt.push(None).accepted is False
    summary = summarise(np.array([[0.0, 0, 0], [2.0, 0, 0], [1.0, 0, 0]]))
    np.testing.assert_allclose(summary.xyz, [1, 0, 0])
    assert summary.n_frames == 3 and summary.spread_mm == pytest.approx(np.sqrt(2 / 3))
    with pytest.raises(ValueError):
        summarise(np.zeros((0, 3)))


def test_accuracy_experiment_small(scene):
    calibration, probe, _ = scene
    results = run_tracking_experiment(calibration, probe, bands=((130, 170),), frames=2, seed=1)
    by = {r.tracker: r for r in results}
    assert set(by) == {"triangulation", "sgbm", "width"}
    assert by["triangulation"].tracked == 1.0 and by["triangulation"].step_rms_mm < 1.0
    assert by["triangulation"].rms_mm < by["width"].rms_mm


def test_track_command(scene, tmp_path, capsys):
    _, probe, renderer = scene
    pose = pose_at(140)
    left, right = renderer.render(pose, RenderOptions(noise_sigma=2, seed=4))
    cv2.imwrite(str(tmp_path / "l.png"), left)
    cv2.imwrite(str(tmp_path / "r.png"), right)
    assert main(["track", str(tmp_path / "l.png"), str(tmp_path / "r.png"), "--calib", str(THESIS_CALIBRATION_PATH), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc) >= {"tip", "centre", "axis", "quality"}
    assert np.linalg.norm(np.array(doc["centre"]) - pose.point(probe.band_centre_mm)) < 1.0
    cv2.imwrite(str(tmp_path / "small.png"), cv2.resize(right, (960, 540)))
    assert main(["track", str(tmp_path / "l.png"), str(tmp_path / "small.png"), "--calib", str(THESIS_CALIBRATION_PATH)]) == 2
    err = capsys.readouterr().err
    assert "960x540" in err and err.count("\n") == 1
    (tmp_path / "junk.png").write_bytes(b"not an image")
    assert main(["track", str(tmp_path / "junk.png"), str(tmp_path / "r.png"), "--calib", str(THESIS_CALIBRATION_PATH)]) == 2
    assert "not a readable image" in capsys.readouterr().err


def test_a_fully_hidden_middle_stripe_leaves_two_that_still_give_the_axis(scene):
    calibration, probe, renderer = scene
    pose = pose_at(130)
    left, right = renderer.render(pose, RenderOptions(noise_sigma=2, seed=8))
    covered = []
    for image, eye in ((left, 0), (right, 1)):
        image = image.copy()
        tracker = StereoTracker(calibration, probe)
        middle = tracker.project(pose.point(probe.stripe_centres_mm[1])[None], eye)[0]
        cv2.circle(image, tuple(int(v) for v in middle), 55, (60, 70, 140), -1)   # a tissue flap over it
        covered.append(image)
    fix = StereoTracker(calibration, probe).track(*covered)
    assert fix.n_stripes == 2
    assert np.linalg.norm(fix.centre - pose.point(probe.band_centre_mm)) < 1.5
    assert np.linalg.norm(fix.tip - pose.tip) < 3.0
