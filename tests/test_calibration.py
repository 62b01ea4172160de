"""Stereo checkerboard calibration (thesis §4.2): files, rendered ground truth, OpenCV's samples, errors."""

import dataclasses
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from snreg.calibration.check import check_images, check_views
from snreg.calibration.checkerboard import Board, find_corners
from snreg.calibration.stereo import calibrate_mono, calibrate_stereo, drop_views, load_image_pairs
from snreg.camera import CalibrationFileError, StereoCalibration, load_calibration, save_calibration, thesis_calibration
from snreg.camera.calibration import _thesis_values
from snreg.cli import build_parser
from snreg.demo.board_render import random_board_poses, render_stereo_board, right_from_left
from snreg.errors import UserError

SAMPLES = Path(__file__).resolve().parent / "data" / "stereo_calib"  # OpenCV's stereo samples: 640x480, 9x6 inner corners, no pair 10
BOARD = Board(10, 7, 10.0)  # thesis §4.2: 11 x 8 squares of 10 mm
N_POSES = 15
MATRICES = ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q")


@pytest.fixture(scope="module")
def truth():
    return thesis_calibration().scaled(0.5)


@pytest.fixture(scope="module")
def rendered(truth):
    """15 noisy, slightly blurred stereo views of the thesis board; (poses, left images, right images)."""
    poses = random_board_poses(truth, BOARD, N_POSES, seed=7)
    pairs = [render_stereo_board(truth, BOARD, pose, noise_sigma=2.0, blur_sigma=0.7, seed=100 + k)
             for k, pose in enumerate(poses)]
    return poses, [left for left, _ in pairs], [right for _, right in pairs]


@pytest.fixture(scope="module")
def rendered_result(rendered):
    _, left, right = rendered
    return calibrate_stereo(left, right, BOARD)


@pytest.fixture(scope="module")
def samples():
    pairs = load_image_pairs(str(SAMPLES / "left*.jpg"), str(SAMPLES / "right*.jpg"))
    return pairs, calibrate_stereo(pairs.left, pairs.right, Board(9, 6, 1.0),
                                   left_names=pairs.left_paths, right_names=pairs.right_paths)


def run_command(argv):
    args = build_parser().parse_args(argv)
    return args.func(args)


def project(K, camera_from_board, points):
    in_camera = points @ camera_from_board[:3, :3].T + camera_from_board[:3, 3]
    pixels = in_camera @ K.T
    return pixels[:, :2] / pixels[:, 2:]


# 1. Files -------------------------------------------------------------------------------------------

def test_file_round_trip(tmp_path, truth):
    calib = dataclasses.replace(truth, rms_reprojection_px=0.123, board_cols=10, board_rows=7, square_mm=10.0, n_views=15)
    save_calibration(calib, tmp_path / "calib.yaml")
    back = load_calibration(tmp_path / "calib.yaml")
    for name in MATRICES:
        np.testing.assert_allclose(getattr(back, name), getattr(calib, name), rtol=1e-12, atol=1e-12, err_msg=name)
    for name in ("image_size", "rms_reprojection_px", "board_cols", "board_rows", "square_mm", "n_views",
                 "created_utc", "snreg_version"):
        assert getattr(back, name) == getattr(calib, name), name


def test_missing_file(tmp_path):
    with pytest.raises(CalibrationFileError, match="no such calibration file"):
        load_calibration(tmp_path / "absent.yaml")


def test_file_that_is_not_yaml(tmp_path):
    path = tmp_path / "notes.yaml"
    path.write_text("hello world, not yaml: [\n")
    with pytest.raises(CalibrationFileError, match="not an OpenCV calibration file"):
        load_calibration(path)


def test_file_missing_a_matrix(tmp_path, truth):
    path = tmp_path / "calib.yaml"
    save_calibration(truth, path)
    text = path.read_text()
    path.write_text(re.sub(r"\nQ: .*?(?=\nrms_reprojection_px)", "", text, flags=re.S))
    with pytest.raises(CalibrationFileError, match=r"rectification is incomplete \(lacks Q\)"):
        load_calibration(path)


def test_shipped_thesis_file_is_appendix_a():
    shipped, typed = thesis_calibration(), _thesis_values()
    for name in MATRICES:
        np.testing.assert_allclose(getattr(shipped, name), getattr(typed, name), rtol=1e-12, atol=1e-12, err_msg=name)
    assert shipped.image_size == typed.image_size == (1920, 1080)
    assert (shipped.board_cols, shipped.board_rows, shipped.square_mm, shipped.n_views) == (10, 7, 10.0, 30)
    assert shipped.K1[0, 0] == pytest.approx(1070.62, abs=0.01) and shipped.baseline_mm == pytest.approx(4.30, abs=0.01)


# 2. Rendered boards against ground truth -------------------------------------------------------------

def test_render_is_deterministic_under_its_seed(truth, rendered):
    poses, left, right = rendered
    again = render_stereo_board(truth, BOARD, poses[0], noise_sigma=2.0, blur_sigma=0.7, seed=100)
    other = render_stereo_board(truth, BOARD, poses[0], noise_sigma=2.0, blur_sigma=0.7, seed=101)
    assert np.array_equal(again[0], left[0]) and np.array_equal(again[1], right[0])
    assert not np.array_equal(other[0], left[0])
    assert all(np.array_equal(a, b) for a, b in zip(poses, random_board_poses(truth, BOARD, N_POSES, seed=7)))
    colour, _ = render_stereo_board(truth, BOARD, poses[0], noise_sigma=2.0, blur_sigma=0.7, seed=100, bgr=True)
    assert colour.shape == (*left[0].shape, 3)
    np.testing.assert_allclose(find_corners(colour, BOARD), find_corners(left[0], BOARD), atol=1e-3)


@pytest.mark.slow
def test_corners_are_found_in_board_order(truth, rendered, rendered_result):
    """Detections match the true projections corner by corner, whatever the board's turn in the image."""
    poses = rendered[0]
    assert rendered_result.view_ids.tolist() == list(range(N_POSES))
    points = BOARD.object_points().astype(float)
    errors = []
    for pose, corners_l, corners_r in zip(poses, rendered_result.left_corners, rendered_result.right_corners):
        errors.append(corners_l - project(truth.K1, pose, points))
        errors.append(corners_r - project(truth.K2, right_from_left(truth) @ pose, points))
    errors = np.linalg.norm(np.array(errors), axis=2)
    assert errors.max() < 0.3 and np.sqrt(np.mean(errors ** 2)) < 0.1


def test_rendered_boards_recover_focal_and_baseline(truth, rendered_result):
    result = rendered_result
    calib = result.calibration
    for K, K_true in ((calib.K1, truth.K1), (calib.K2, truth.K2)):
        np.testing.assert_allclose(np.diag(K)[:2], np.diag(K_true)[:2], rtol=0.005)
        np.testing.assert_allclose(K[:2, 2], K_true[:2, 2], atol=2.0)
    assert calib.baseline_mm == pytest.approx(truth.baseline_mm, rel=0.01)
    angle = np.degrees(np.arccos(np.clip((np.trace(calib.R @ truth.R.T) - 1) / 2, -1, 1)))
    assert angle < 0.05
    assert calib.image_size == truth.image_size
    assert (calib.board_cols, calib.board_rows, calib.square_mm, calib.n_views) == (10, 7, 10.0, N_POSES)
    assert result.rms_px < 0.1 and result.eye_rms_px.max() < 0.1 and result.mono_rms_px.max() < 0.1
    assert result.view_errors_px.shape == (N_POSES, 2) and result.skipped == ()
    # 0.04 px corner noise at a 4.3 mm baseline and 150-400 mm (f = 535 px): about a millimetre in depth
    assert 0.0 < result.reconstruction_error_mm < 2.0


def test_mono_calibration(truth, rendered):
    mono = calibrate_mono(rendered[1][:8], BOARD)
    np.testing.assert_allclose(np.diag(mono.K)[:2], np.diag(truth.K2)[:2], rtol=0.005)
    assert mono.D.shape == (1, 5) and mono.view_errors_px.shape == (8,) and mono.rms_px < 0.1


# 3. OpenCV's real samples ---------------------------------------------------------------------------

def test_samples_agree_with_plain_opencv(samples):
    pairs, result = samples
    assert result.n_views == 13 and result.skipped == ()
    objects = [Board(9, 6, 1.0).object_points()] * result.n_views
    left, right = list(result.left_corners), list(result.right_corners)
    rms_l, K1, D1, _, _ = cv2.calibrateCamera(objects, left, (640, 480), None, None)
    rms_r, K2, D2, _, _ = cv2.calibrateCamera(objects, right, (640, 480), None, None)
    rms, *_, R, T, _, _ = cv2.stereoCalibrate(objects, left, right, K1, D1, K2, D2, (640, 480))
    np.testing.assert_allclose(result.mono_rms_px, [rms_l, rms_r], rtol=1e-6)
    # our joint refinement starts where OpenCV's fixed-intrinsics stereo calibration ends up, and can only improve
    assert 0.9 * rms <= result.rms_px <= rms + 1e-9
    baseline_squares = result.calibration.baseline_mm / result.board.square_mm
    assert baseline_squares == pytest.approx(np.linalg.norm(T) / 1.0, rel=0.01)
    assert result.rms_px < 0.3 and result.reconstruction_error_mm < 0.02  # squares


@pytest.mark.slow
def test_command_writes_a_loadable_file(samples, tmp_path, capsys):
    out = tmp_path / "calib.yaml"
    assert run_command(["calibrate", "stereo", "--left", str(SAMPLES / "left*.jpg"), "--right", str(SAMPLES / "right*.jpg"),
                        "--board", "9x6", "--square", "1", "-o", str(out)]) == 0
    calib = load_calibration(out)
    assert (calib.board_cols, calib.board_rows, calib.n_views, calib.image_size) == (9, 6, 13, (640, 480))
    assert calib.baseline_mm == pytest.approx(samples[1].calibration.baseline_mm, rel=1e-9)
    text = capsys.readouterr().out
    assert "stereo" in text and "baseline" in text and "squares" in text and "reconstruction error" in text
    assert re.search(r"^\s+8\s+left09\.jpg\s+right09\.jpg", text, flags=re.M)  # the table skips the absent pair 10


# 4. Dropping views, bad input -----------------------------------------------------------------------

def test_drop_views(rendered_result):
    dropped = drop_views(rendered_result, [3, 7])
    assert dropped.n_views == dropped.calibration.n_views == N_POSES - 2
    assert 3 not in dropped.view_ids and 7 not in dropped.view_ids and dropped.view_errors_px.shape == (N_POSES - 2, 2)
    kept = ~np.isin(rendered_result.view_ids, [3, 7])
    np.testing.assert_array_equal(dropped.left_corners, rendered_result.left_corners[kept])
    assert dropped.rms_px != rendered_result.rms_px
    with pytest.raises(ValueError, match="cannot drop view"):
        drop_views(dropped, [3])
    with pytest.raises(ValueError, match="leaves 2"):
        drop_views(dropped, dropped.view_ids[:-2])


def test_command_drop(rendered, tmp_path, capsys):
    _, left, right = rendered
    for k in range(5):
        cv2.imwrite(str(tmp_path / f"l{k}.png"), left[k])
        cv2.imwrite(str(tmp_path / f"r{k}.png"), right[k])
    out = tmp_path / "calib.yaml"
    assert run_command(["calibrate", "stereo", "--left", str(tmp_path / "l*.png"), "--right", str(tmp_path / "r*.png"),
                        "--board", "10x7", "--square", "10", "-o", str(out), "--drop", "1,3"]) == 0
    assert load_calibration(out).n_views == 3
    rows = re.findall(r"^\s+(\d+)\s+l\d\.png", capsys.readouterr().out, flags=re.M)
    assert rows == ["0", "2", "4"]


def write_images(folder, names, size=(64, 48)):
    folder.mkdir(exist_ok=True)
    for name in names:
        cv2.imwrite(str(folder / name), np.full((size[1], size[0]), 128, np.uint8))


def test_load_pairs_in_natural_order(tmp_path):
    write_images(tmp_path, ["left2.png", "left10.png", "right2.png", "right10.png"])
    pairs = load_image_pairs(str(tmp_path / "left*.png"), str(tmp_path / "right*.png"))
    assert [Path(p).name for p in pairs.left_paths] == ["left2.png", "left10.png"]
    assert pairs.left[0].shape == (48, 64) and len(pairs.right) == 2


@pytest.mark.parametrize("setup, fragment", [
    (lambda d: None, "no files match the left pattern"),
    (lambda d: write_images(d, ["left1.png", "left2.png", "right1.png"]), "counts must match"),
    (lambda d: (write_images(d, ["left1.png", "right1.png"]), write_images(d, ["left2.png", "right2.png"], (32, 24))),
     "differ in size"),
    (lambda d: (write_images(d, ["right1.png"]), (d / "left1.png").write_text("not an image")), "not a readable image"),
])
def test_load_pairs_bad_input(tmp_path, setup, fragment):
    setup(tmp_path)
    with pytest.raises(ValueError, match=fragment):
        load_image_pairs(str(tmp_path / "left*.png"), str(tmp_path / "right*.png"))


@pytest.fixture(scope="module")
def small_pairs(truth):
    """Three pairs at a quarter of the thesis resolution (480x270), the board facing the camera 250 mm away;
    small, so that a search in vain is quick."""
    small = truth.scaled(0.5)
    poses = [np.array([[1, 0, 0, x], [0, 1, 0, -30], [0, 0, 1, 250], [0, 0, 0, 1]], float) for x in (-80, -45, -10)]
    return [render_stereo_board(small, BOARD, pose, noise_sigma=2.0, seed=k) for k, pose in enumerate(poses)]


def test_wrong_board_size(small_pairs):
    left, right = [p[0] for p in small_pairs], [p[1] for p in small_pairs]
    with pytest.raises(ValueError, match=r"found in both images of only 0 of 3 pairs, need 3; not found in left image 0, "
                                         r"left image 1, left image 2; check the board size"):
        calibrate_stereo(left, right, Board(11, 8, 10.0))  # squares counted instead of inner corners
    with pytest.raises(ValueError, match="3 left but 2 right"):
        calibrate_stereo(left, right[:2], BOARD)
    assert find_corners(np.full((240, 320), 200, np.uint8), BOARD) is None


@pytest.mark.parametrize("board, square", [("10by7", "10"), ("7x7", "10"), ("10x7", "-1")])
def test_command_bad_board(tmp_path, board, square):
    with pytest.raises((UserError, SystemExit)) as caught:     # a negative square is argparse's (exit status 2)
        run_command(["calibrate", "stereo", "--left", str(tmp_path / "l*.png"), "--right", str(tmp_path / "r*.png"),
                     "--board", board, "--square", square, "-o", str(tmp_path / "c.yaml")])
    assert caught.type is UserError or caught.value.code == 2


def test_command_no_files(tmp_path):
    with pytest.raises(UserError, match="no files match"):
        run_command(["calibrate", "stereo", "--left", str(tmp_path / "l*.png"), "--right", str(tmp_path / "r*.png"),
                     "--board", "10x7", "--square", "10", "-o", str(tmp_path / "c.yaml")])


# 5. The calibration check: good against R turned by one degree ------------------------------------------

def turned(calib, axis, degrees=1.0):
    """``calib`` with R turned by ``degrees`` about ``axis`` (left-camera frame), rectification redone."""
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(np.radians(degrees) * np.asarray(axis, float)).as_matrix() @ calib.R
    return StereoCalibration.from_pair(calib.image_size, calib.K1, calib.D1, calib.K2, calib.D2, R, calib.T)


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 1, 0), (0, 0, 1)])
def test_check_tells_the_samples_calibration_from_one_with_R_turned_1_degree(samples, axis):
    _, result = samples
    good = check_views(result.calibration, result.left_corners, result.right_corners, result.board)
    spoiled = check_views(turned(result.calibration, axis), result.left_corners, result.right_corners, result.board)
    assert good.verdict == "good" and good.epipolar_rms_px < 0.3 and abs(good.scale_error) < 0.005
    assert spoiled.verdict == "bad", spoiled.summary()
    # about x the rows part; about y (the baseline's normal in the image plane) every disparity shifts: the scale
    assert spoiled.epipolar_rms_px > 5 if axis == (1, 0, 0) else True
    assert abs(spoiled.scale_error) > 0.05 if axis == (0, 1, 0) else True


@pytest.mark.parametrize("axis", [(1, 0, 0), (0, 1, 0), (0, 0, 1)])
def test_check_tells_the_true_calibration_from_one_with_R_turned_1_degree_on_rendered_boards(truth, rendered_result, axis):
    good = check_views(truth, rendered_result.left_corners, rendered_result.right_corners, BOARD)
    spoiled = check_views(turned(truth, axis), rendered_result.left_corners, rendered_result.right_corners, BOARD)
    assert good.verdict == "good" and good.epipolar_rms_px < 0.2, good.summary()
    assert spoiled.verdict == "bad" and spoiled.reasons, spoiled.summary()
    assert good.as_json()["verdict"] == "good" and set(good.as_json()) >= {"epipolar_rms_px", "reconstruction_mm", "views",
                                                                           "verdict", "reasons"}


def test_copies_of_one_view_are_flagged_and_their_calibration_fails_the_check(truth, rendered, rendered_result):
    _, left, right = rendered
    copies = calibrate_stereo([left[0]] * 3, [right[0]] * 3, BOARD)
    assert copies.distinct_views == 1 and copies.repeated_views == ((1, 0), (2, 0))
    warnings = " ".join(copies.warnings())
    assert "near-identical views" in warnings and "provisional" in warnings and "bad" in warnings
    assert copies.check.verdict == "bad" and copies.check.epipolar_rms_px > 10      # its own views betray it
    assert rendered_result.distinct_views >= 8 and not any("provisional" in w for w in rendered_result.warnings())
    other_views = check_views(copies.calibration, rendered_result.left_corners, rendered_result.right_corners, BOARD)
    assert other_views.verdict == "bad"


@pytest.mark.slow
def test_check_command_on_the_samples(samples, tmp_path, capsys):
    _, result = samples
    good, spoiled = tmp_path / "good.yaml", tmp_path / "spoiled.yaml"
    save_calibration(result.calibration, good)
    save_calibration(turned(result.calibration, (1, 0, 0)), spoiled)
    figures = {}
    for path in (good, spoiled):
        assert run_command(["calibrate", "check", str(path), "--left", str(SAMPLES / "left*.jpg"), "--right",
                            str(SAMPLES / "right*.jpg"), "--board", "9x6", "--square", "1", "--json"]) == 0
        figures[path.stem] = json.loads(capsys.readouterr().out)
    assert figures["good"]["verdict"] == "good" and figures["spoiled"]["verdict"] == "bad"
    assert figures["good"]["views"] == 13 and "epipolar error" in figures["spoiled"]["reasons"][0]
    assert run_command(["calibrate", "check", str(good), "--left", str(SAMPLES / "left0*.jpg"), "--right",
                        str(SAMPLES / "right0*.jpg"), "--board", "9x6", "--square", "1"]) == 0
    text = capsys.readouterr().out
    assert "verdict: good" in text and "left01.jpg/right01.jpg" in text


def test_check_refuses_images_of_another_size_and_boards_not_found(truth, rendered):
    _, left, right = rendered
    with pytest.raises(ValueError, match="calibration is for 960x540"):
        check_images(truth, [cv2.resize(left[0], (480, 270))], [cv2.resize(right[0], (480, 270))], BOARD)
    with pytest.raises(ValueError, match="found in no pair"):
        check_images(truth, left[:1], right[:1], Board(11, 8, 10.0))
