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


@pytest.mark.slow
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


def test_a_probe_running_out_of_the_image_is_said_to_instead_of_what_its_stripes_left_in_view_show(scene):
    calibration, probe, renderer = scene
    tracker = StereoTracker(calibration, probe)
    left, right = renderer.render(pose_at(150, x=120))               # the stripes' far end beyond the right edge
    with pytest.raises(TrackingError, match="its stripes run out of the left image .*bring the probe further into"):
        tracker.track(left, right)
    tracker.track(*renderer.render(pose_at(150, x=110)))             # all in view: a fix


def test_a_probe_whose_tip_end_cannot_be_told_has_no_fix_rather_than_a_guess(scene):
    """Tip at the bottom edge, back end beyond the right edge: the three stripes read the same from either end; the
    old guess put the tip 60 mm off, at the back end."""
    calibration, probe, renderer = scene
    with pytest.raises(TrackingError, match="which end is the tip cannot be told"):
        StereoTracker(calibration, probe).track(*renderer.render(ProbePose.make([55.0, 50.0, 100.0], AXIS)))


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


@pytest.mark.slow
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


# Distractors: green things that are not the probe -------------------------------------------------------

DISTRACTORS = {
    "two round fiducials 7.2 mm apart": RenderOptions(noise_sigma=3, seed=1, probe=False,
                                                      fiducials_mm=((20.0, 30.0), (27.2, 30.0))),
    "three fiducials 10 mm apart in a row": RenderOptions(noise_sigma=3, seed=1, probe=False,
                                                          fiducials_mm=((0.0, 30.0), (10.0, 30.0), (20.0, 30.0))),
    "greenish blobs at the border": RenderOptions(noise_sigma=3, seed=1, probe=False, border_blobs=4),
    "specular highlights with a green fringe": RenderOptions(noise_sigma=3, seed=1, probe=False, highlights=6),
}


@pytest.fixture(scope="module")
def half_scene():
    """The thesis cameras at half resolution (960x540): the distractors are in mm, the renders 4x cheaper."""
    calibration, probe = thesis_calibration().scaled(0.5), default_probe_model()
    return calibration, probe, StereoRenderer(calibration, probe)


@pytest.mark.parametrize("name", list(DISTRACTORS))
def test_distractors_alone_give_no_fix(half_scene, name):
    calibration, probe, renderer = half_scene
    left, right = renderer.render(pose_at(120), DISTRACTORS[name])
    mask = cv2.inRange(cv2.cvtColor(left, cv2.COLOR_BGR2HSV), probe.hsv_low, probe.hsv_high)
    assert np.count_nonzero(mask) > 200                      # there is something green to be fooled by
    for method in ("triangulation", "sgbm", "width"):
        with pytest.raises(TrackingError, match="no probe"):
            StereoTracker(calibration, probe, method=method).track(left, right)


def test_the_probe_is_found_beside_every_distractor(half_scene):
    calibration, probe, renderer = half_scene
    pose = pose_at(120)
    left, right = renderer.render(pose, RenderOptions(noise_sigma=3, seed=1, fiducials_mm=((20.0, 30.0), (27.2, 30.0)),
                                                      border_blobs=4, highlights=6))
    for method, tolerance_mm in (("triangulation", 1.0), ("sgbm", 2.0), ("width", 8.0)):
        fix = StereoTracker(calibration, probe, method=method).track(left, right)
        assert fix.n_stripes == 3 and np.linalg.norm(fix.centre - pose.point(probe.band_centre_mm)) < tolerance_mm, method


def test_a_fix_outside_the_depth_range_is_refused(half_scene):
    calibration, probe, renderer = half_scene
    left, right = renderer.render(pose_at(120), RenderOptions(noise_sigma=2, seed=3))
    assert StereoTracker(calibration, probe, depth_range_mm=(60, 200)).track(left, right).n_stripes == 3
    with pytest.raises(TrackingError, match="no probe"):
        StereoTracker(calibration, probe, depth_range_mm=(200, 400)).track(left, right)
    with pytest.raises(ValueError, match="depth range"):
        StereoTracker(calibration, probe, depth_range_mm=(50, 20))


@pytest.mark.parametrize("method", ["triangulation", "sgbm"])
def test_standard_definition_images(method):
    """360 px wide, as an SD endoscope: the disparity window follows from the calibration and the depth range
    (the thesis' fixed 288 left nothing valid in the first 288 columns)."""
    calibration, probe = thesis_calibration().scaled(0.1875), default_probe_model()
    assert calibration.image_size == (360, 202)
    pose = ProbePose.make([-10.0, 3.0, 80.0], AXIS)
    left, right = StereoRenderer(calibration, probe).render(pose, RenderOptions(noise_sigma=2, seed=1))
    fix = StereoTracker(calibration, probe, method=method).track(left, right)
    assert np.linalg.norm(fix.centre - pose.point(probe.band_centre_mm)) < 2.0


def test_track_command_no_probe_width_method_and_depth_range(half_scene, tmp_path, capsys):
    calibration, probe, renderer = half_scene
    from snreg.camera import save_calibration

    save_calibration(calibration, tmp_path / "half.yaml")
    pose = pose_at(140)
    for name, options in (("probe", RenderOptions(noise_sigma=2, seed=4)),
                          ("fiducials", DISTRACTORS["two round fiducials 7.2 mm apart"])):
        for eye, image in zip("lr", renderer.render(pose, options)):
            cv2.imwrite(str(tmp_path / f"{name}_{eye}.png"), image)
    common = ["--calib", str(tmp_path / "half.yaml"), "--json"]
    assert main(["track", str(tmp_path / "probe_l.png"), str(tmp_path / "probe_r.png"), "--method", "width", *common]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["method"] == "width" and np.linalg.norm(np.array(doc["centre"]) - pose.point(probe.band_centre_mm)) < 10.0
    for method in ("triangulation", "sgbm", "width"):
        assert main(["track", str(tmp_path / "fiducials_l.png"), str(tmp_path / "fiducials_r.png"), "--method", method,
                     *common]) == 2
        captured = capsys.readouterr()
        assert captured.out == "" and captured.err.startswith("snreg: no probe") and captured.err.count("\n") == 1
    assert main(["track", str(tmp_path / "probe_l.png"), str(tmp_path / "probe_r.png"), "--depth-range", "150,300",
                 *common]) == 2
    assert "outside the working depth range 150-300 mm" in capsys.readouterr().err
