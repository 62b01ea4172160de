"""The pivot distance from the camera turning over tissue (issue 27, self-calibration): the free pose fit against exact
synthetic motion; the pose follower and the pivot fit against seeded renders of a turn about the trocar (the probe in
view, the IMU with 0.2 degrees of noise); the verdict's refusals; ``snreg calibrate trocar tissue``'s contract."""

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.calibration.pivot import MIN_POSES
from snreg.calibration.tissue_pivot import BAD_TURN_DEG, MIN_VIEWS, tissue_pivot_calibration
from snreg.calibration.trocar_fit import fit_tissue_pivot
from snreg.camera import save_calibration, thesis_calibration
from snreg.chain import ChainCalibration
from snreg.cli import main
from snreg.demo.renderer import RenderOptions
from snreg.demo.tissue import TissueSurface
from snreg.demo.tissue_pivot import TissuePivotScene
from snreg.geometry import euler_from_rotation, invert, make_transform, rotation_distance_deg
from snreg.odometry.motion import Observations
from snreg.odometry.poses import TissuePoseFollower, fit_rigid
from snreg.probe import default_probe_model

SCALE = 0.25            # 480 x 270 renders: fast, and the follower's working scale is then the image's own
PAIRS = 36              # one cycle: 1.7 degrees between pairs


@pytest.fixture(scope="module")
def calibration():
    return thesis_calibration().scaled(SCALE)


@pytest.fixture(scope="module")
def turn(calibration):
    """A turn of +-10 by +-6 degrees about the trocar over tissue, the probe in view, rendered once."""
    scene = TissuePivotScene(calibration, frames_per_cycle=PAIRS, seed=1)
    for k in range(PAIRS):
        scene.render(k)
    return scene


@pytest.fixture(scope="module")
def small_turn(calibration):
    """A turn of +-1.5 by +-1 degrees over the same tissue: a spread of 3 degrees."""
    scene = TissuePivotScene(calibration, frames_per_cycle=12, tilt_deg=(1.5, 1.0), seed=2)
    for k in range(12):
        scene.render(k)
    return scene


def follow(calibration, pairs):
    """Poses (n, 4, 4) of the tracked pairs among ``pairs`` ((left, right) BGR), their indices, and every estimate."""
    follower = TissuePoseFollower(calibration, probe=default_probe_model())
    estimates = [follower.update(left, right) for left, right in pairs]
    tracked = [e.index for e in estimates if e.tracked]
    return np.array([estimates[k].tissue_from_camera for k in tracked]), tracked, estimates


def rendered(scene, n):
    return [scene.render(k) for k in range(n)]


# -- the free pose fit, on exact synthetic motion ----------------------------------------------------------------
def synthetic(seed=0):
    """Observations of 150 tissue points 70-110 mm ahead after the camera turned 4 degrees and moved 9 mm."""
    rng = np.random.default_rng(seed)
    calib = thesis_calibration()
    points = np.column_stack([rng.uniform(-40, 40, 150), rng.uniform(-25, 25, 150), rng.uniform(70, 110, 150)])
    rotation = Rotation.from_euler("xyz", [3.0, -2.0, 1.5], degrees=True).as_matrix()
    translation = np.array([6.0, -4.0, 5.0])
    now = points @ rotation.T + translation
    right_from_left = make_transform(calib.R, calib.T.ravel())
    right = now @ right_from_left[:3, :3].T + right_from_left[:3, 3]
    obs = Observations(points, now[:, :2] / now[:, 2:], right[:, :2] / right[:, 2:], right_from_left,
                       float(calib.K1[0, 0]) / 2.0)
    return obs, rotation, translation


def test_the_free_fit_finds_an_exact_motion_from_a_start_that_is_not_quite_a_rotation():
    obs, rotation, translation = synthetic()
    start = 1.001 * Rotation.from_rotvec(np.radians([1.0, -0.5, 0.8])).as_matrix() @ rotation      # 1 deg off, scaled
    fit = fit_rigid(obs, start, translation + [1.0, -1.0, 2.0])
    assert np.allclose(fit.rotation @ fit.rotation.T, np.eye(3), atol=1e-12)
    assert rotation_distance_deg(fit.rotation, rotation) < 1e-5 and np.abs(fit.translation - translation).max() < 1e-4
    assert fit.inliers.all() and fit.rms_px < 1e-4


def test_the_free_fit_leaves_out_points_that_move_against_the_tissue():
    obs, rotation, translation = synthetic(1)
    moved = obs.left.copy()
    moved[:40] += 1.5 / obs.focal_px                       # a quarter of the points on the probe, 1.5 px off
    noisy = moved + np.random.default_rng(2).normal(0.0, 0.1 / obs.focal_px, moved.shape)
    fit = fit_rigid(Observations(obs.points, noisy, obs.right, obs.right_from_left, obs.focal_px), rotation,
                    translation)
    assert not fit.inliers[:40].any() and fit.inliers[40:].mean() > 0.95
    assert rotation_distance_deg(fit.rotation, rotation) < 0.01 and np.abs(fit.translation - translation).max() < 0.05


# -- the follower and the pivot fit, on renders ------------------------------------------------------------------
@pytest.mark.slow
def test_a_turn_over_tissue_gives_the_pivot_distance_and_the_imu_rotation(calibration, turn):
    poses, tracked, _ = follow(calibration, rendered(turn, PAIRS))
    assert len(tracked) == PAIRS
    truth = np.array([invert(turn.trocar_from_camera(0)) @ turn.trocar_from_camera(k) for k in tracked])
    assert np.abs(poses[:, :3, 3] - truth[:, :3, 3]).max() < 1.0              # mm, over 55 mm of camera travel
    fit = fit_tissue_pivot(poses, np.array([turn.earth_from_imu(k) for k in tracked]))
    pivot, chain = fit.pivot, fit.chain
    error = chain.trocar_camera_mm - turn.true_chain.trocar_camera_mm
    rotation_error = float(rotation_distance_deg(chain.imu_from_camera, turn.true_chain.imu_from_camera))
    print(f"tissue pivot: {pivot.trocar_camera_mm:.2f} mm (error {error:+.2f}, standard error {pivot.distance_sd_mm:.2f}), "
          f"RMS {pivot.rms_mm:.2f} mm, turn {pivot.tilt_range_deg:.1f} degrees; IMU-camera error {rotation_error:.2f} deg")
    assert abs(error) < 2.0 and pivot.verdict == "good", pivot.advice
    assert rotation_error < 1.0 and fit.hand_eye.rms_deg < 1.0         # the IMU's 0.2 degrees per axis


@pytest.mark.slow
def test_another_tissue_and_distance(calibration):
    surface = TissueSurface(depth_mm=225.0, relief_mm=5.0, relief_scale_mm=12.0, tilt_deg=(-6.0, 10.0), seed=8,
                            texture_seed=21)
    scene = TissuePivotScene(calibration, frames_per_cycle=24, tilt_deg=(7.0, 9.0), trocar_camera_mm=140.0,
                             surface=surface, seed=4)
    poses, tracked, _ = follow(calibration, rendered(scene, 24))
    pivot = tissue_pivot_calibration(poses)
    print(f"tissue pivot: {pivot.trocar_camera_mm:.2f} mm of 140, {len(tracked)} views, {pivot.verdict}")
    assert len(tracked) >= 22 and abs(pivot.trocar_camera_mm - 140.0) < 2.0 and pivot.verdict != "bad"


@pytest.mark.slow
def test_too_little_turn_is_judged_bad(calibration, small_turn):
    poses, tracked, _ = follow(calibration, rendered(small_turn, 12))
    pivot = tissue_pivot_calibration(poses)
    assert len(tracked) == 12 and pivot.tilt_range_deg < BAD_TURN_DEG
    assert pivot.verdict == "bad" and "turned through only 3.0 degrees" in pivot.advice


@pytest.mark.slow
def test_a_trocar_that_moved_while_turning_is_judged_bad(calibration, turn):
    """Half-way the trocar is pushed 5 mm sideways (the tissue moved against it): two pivots, not one."""
    shifted = make_transform(np.eye(3), [5.0, 0.0, 0.0])
    pairs = [turn.render(k) if k < PAIRS // 2 else
             turn.video.scene.render(shifted @ turn.trocar_from_camera(k), None, RenderOptions(noise_sigma=2.0, seed=k))
             for k in range(PAIRS)]
    poses, tracked, _ = follow(calibration, pairs)
    pivot = tissue_pivot_calibration(poses)
    assert len(tracked) >= PAIRS - 2
    assert pivot.verdict == "bad" and ("did not turn about one fixed point" in pivot.advice
                                       or "agree on one pivot" in pivot.advice), pivot.advice


def test_too_few_views_are_judged_bad_and_fewer_than_four_refused():
    turns = Rotation.from_euler("xy", [[8, 0], [-8, 0], [0, 8], [0, -8], [6, 6], [-6, -6]], degrees=True)
    poses = make_transform(turns.as_matrix(), turns.apply([0.0, 0.0, 158.0]))
    pivot = tissue_pivot_calibration(poses)
    assert pivot.trocar_camera_mm == pytest.approx(158.0) and len(poses) < MIN_VIEWS
    assert pivot.verdict == "bad" and pivot.advice.startswith("only 6 views agree on a pivot")
    with pytest.raises(ValueError, match=f"need at least {MIN_POSES}"):
        tissue_pivot_calibration(poses[:3])


def test_a_covered_pair_is_lost_in_words_and_the_next_found_again(calibration, turn):
    pairs = rendered(turn, 8)
    grey = np.full_like(pairs[0][0], 100)
    _, tracked, estimates = follow(calibration, [*pairs[:4], (grey, grey), *pairs[5:]])
    assert tracked == [0, 1, 2, 3, 5, 6, 7]
    assert estimates[4].tissue_from_camera is None and "no tissue texture" in estimates[4].reason


# -- snreg calibrate trocar tissue -------------------------------------------------------------------------------
def write_recording(scene, pairs, folder):
    """The pairs as ``left/NNNN.png``, ``right/NNNN.png``, the IMU per pair as ``imu.csv``, and the calibration."""
    for eye in ("left", "right"):
        (folder / eye).mkdir(parents=True)
    rows = []
    for k, (left, right) in enumerate(pairs):
        cv2.imwrite(str(folder / "left" / f"{k:04d}.png"), left)
        cv2.imwrite(str(folder / "right" / f"{k:04d}.png"), right)
        rows.append("{:.6f},{:.6f},{:.6f}\n".format(*euler_from_rotation(scene.earth_from_imu(k))))
    (folder / "imu.csv").write_text("yaw,pitch,roll\n" + "".join(rows))
    save_calibration(scene.calibration, folder / "calib.yaml")
    return ["calibrate", "trocar", "tissue", "--left", str(folder / "left" / "*.png"),
            "--right", str(folder / "right" / "*.png"), "--calib", str(folder / "calib.yaml")]


@pytest.mark.slow
def test_command_tissue_writes_the_chain_and_prints_the_contract(turn, tmp_path, capsys):
    argv = write_recording(turn, rendered(turn, PAIRS), tmp_path)
    assert main([*argv, "--imu-csv", str(tmp_path / "imu.csv"), "-o", str(tmp_path / "chain.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert {"trocar_camera_mm", "distance_sd_mm", "rms_mm", "tilt_range_deg", "pivot_camera_mm", "pairs", "views",
            "used", "lost", "verdict", "advice", "imu_from_camera", "chain"} <= set(doc)
    assert (doc["pairs"], doc["views"], doc["lost"], doc["verdict"]) == (PAIRS, PAIRS, 0, "good")
    assert doc["chain"] == str(tmp_path / "chain.json") and set(doc["imu_from_camera"]) >= {"yaw", "pitch", "roll"}
    written = json.loads((tmp_path / "chain.json").read_text())
    chain = ChainCalibration.from_dict(written)
    assert written["method"] == "tissue" and chain.trocar_camera_mm == pytest.approx(doc["trocar_camera_mm"], abs=1e-3)
    assert abs(chain.trocar_camera_mm - turn.true_chain.trocar_camera_mm) < 2.0
    assert rotation_distance_deg(chain.imu_from_camera, turn.true_chain.imu_from_camera) < 1.0
    assert main(argv) == 0                                   # no IMU: the text report, the identity assumed
    out = capsys.readouterr().out
    assert "camera pose found in 36 of 36 pairs" in out and "verdict: good" in out and "identity assumed" in out


def test_command_tissue_refuses_a_bad_recording_and_writes_no_chain(small_turn, tmp_path, capsys):
    argv = write_recording(small_turn, rendered(small_turn, 12), tmp_path)
    assert main([*argv, "-o", str(tmp_path / "chain.json")]) == 2
    out, err = capsys.readouterr()
    assert "verdict: bad" in out and err.count("\n") == 1 and "refused" in err and "no chain file written" in err
    assert not (tmp_path / "chain.json").exists()
