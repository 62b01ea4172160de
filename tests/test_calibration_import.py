"""Calibrations from other tools (``snreg calibrate import``, :mod:`snreg.camera.formats`) and the loader's messages.

Each layout is written here the way its tool writes it, from one known calibration with lens distortion, and
must come back as that calibration (K, D, R, T; the rectification computed where the files lack it).
"""

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.camera import CalibrationFileError, StereoCalibration, import_calibration, load_calibration
from snreg.cli import main

SIZE = (640, 480)


@pytest.fixture(scope="module")
def truth() -> StereoCalibration:
    K1 = np.array([[536.2, 0.0, 342.1], [0.0, 536.0, 235.9], [0.0, 0.0, 1.0]])
    K2 = np.array([[534.8, 0.0, 334.6], [0.0, 534.6, 242.7], [0.0, 0.0, 1.0]])
    D1 = np.array([[-0.28, 0.08, 0.0012, -0.0003, 0.02]])
    D2 = np.array([[-0.27, 0.05, -0.0004, 0.0008, 0.06]])
    R = Rotation.from_euler("xyz", [0.4, -0.9, 0.2], degrees=True).as_matrix()
    T = np.array([-99.8, 1.2, 0.4])
    return StereoCalibration.from_pair(SIZE, K1, D1, K2, D2, R, T)


def write_storage(path, values: dict) -> None:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in values.items():
        fs.write(key, value)
    fs.release()


def write_text(path, matrix) -> None:
    path.write_text("\n".join(" ".join(f"{v:.12g}" for v in row) for row in np.atleast_2d(matrix)) + "\n")


def same_cameras(a: StereoCalibration, b: StereoCalibration) -> None:
    assert a.image_size == b.image_size
    for name in ("K1", "K2", "R"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-9, err_msg=name)
    for name in ("D1", "D2", "T"):
        np.testing.assert_allclose(np.ravel(getattr(a, name)), np.ravel(getattr(b, name)), atol=1e-9, err_msg=name)


def same_rectification(a: StereoCalibration, b: StereoCalibration) -> None:
    for name in ("R1", "R2", "P1", "P2", "Q"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), atol=1e-6, err_msg=name)


def test_opencv_stereo_calib_layout_with_and_without_rectification(tmp_path, truth):
    write_storage(tmp_path / "intrinsics.yml", {"M1": truth.K1, "D1": truth.D1, "M2": truth.K2, "D2": truth.D2})
    write_storage(tmp_path / "extrinsics.yml", {"R": truth.R, "T": truth.T})
    imported = import_calibration([tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml"], SIZE)
    same_cameras(imported.calibration, truth)
    same_rectification(imported.calibration, truth)
    assert imported.rectification_computed and "OpenCV" in imported.layout
    # stereo_calib.cpp also writes its rectification (alpha -1 there): kept as given
    R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(truth.K1, truth.D1, truth.K2, truth.D2, SIZE, truth.R, truth.T,
                                                flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1)
    write_storage(tmp_path / "extrinsics.yml", {"R": truth.R, "T": truth.T, "R1": R1, "R2": R2, "P1": P1, "P2": P2, "Q": Q})
    given = import_calibration([tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml"], SIZE)
    assert not given.rectification_computed
    np.testing.assert_allclose(given.calibration.P2, P2)


def test_snreg_keys_without_rectification_load_and_import(tmp_path, truth):
    path = tmp_path / "plain.yaml"
    write_storage(path, {"image_width": SIZE[0], "image_height": SIZE[1], "K1": truth.K1, "D1": truth.D1,
                         "K2": truth.K2, "D2": truth.D2, "R": truth.R, "T": truth.T})
    loaded = load_calibration(path)                      # track --calib, the rig... accept it as it is
    same_cameras(loaded, truth)
    same_rectification(loaded, truth)
    imported = import_calibration([path])                # the size comes from the file
    same_cameras(imported.calibration, truth)
    with pytest.raises(CalibrationFileError, match="for 640x480 images but 1280x960 was given"):
        import_calibration([path], (1280, 960))


@pytest.mark.parametrize("distortion_values", [5, 4])
def test_niftk_folder_of_xml_files(tmp_path, truth, distortion_values):
    folder = tmp_path / "calib"
    folder.mkdir()
    write_storage(folder / "calib.left.intrinsic.xml", {"calib_left_intrinsic": truth.K1})
    write_storage(folder / "calib.left.distortion.xml", {"calib_left_distortion": truth.D1[:, :distortion_values]})
    write_storage(folder / "calib.right.intrinsic.xml", {"calib_right_intrinsic": truth.K2})
    write_storage(folder / "calib.right.distortion.xml", {"calib_right_distortion": truth.D2[:, :distortion_values]})
    write_storage(folder / "calib.r2l.rotation.xml", {"calib_r2l_rotation": truth.R})
    write_storage(folder / "calib.r2l.translation.xml", {"calib_r2l_translation": truth.T.reshape(3, 1)})
    imported = import_calibration([folder], SIZE)
    assert "NifTK" in imported.layout
    np.testing.assert_allclose(imported.calibration.K1, truth.K1)
    np.testing.assert_allclose(imported.calibration.R, truth.R)                    # x_right = R x_left + T, as named
    np.testing.assert_allclose(imported.calibration.T.ravel(), truth.T.ravel())
    np.testing.assert_allclose(imported.calibration.D1.ravel(), truth.D1.ravel()[:distortion_values])
    if distortion_values == 5:
        same_rectification(imported.calibration, truth)


@pytest.mark.parametrize("extrinsics", ["l2r.txt", "l2r.4x4"])
def test_niftk_folder_of_text_files(tmp_path, truth, extrinsics):
    folder = tmp_path / "calib"
    folder.mkdir()
    write_text(folder / "viking.calib.left.intrinsics.txt", truth.K1)            # a prefix, as in UCL's datasets
    write_text(folder / "viking.calib.left.distortion.txt", truth.D1)
    write_text(folder / "viking.calib.right.intrinsics.txt", truth.K2)
    write_text(folder / "viking.calib.right.distortion.txt", truth.D2)
    if extrinsics == "l2r.txt":
        write_text(folder / "calib.l2r.txt", np.vstack([truth.R, truth.T.ravel()]))   # three rows of R, then T
    else:
        homogeneous = np.eye(4)
        homogeneous[:3, :3], homogeneous[:3, 3] = truth.R, truth.T.ravel()
        write_text(folder / "calib.l2r.4x4", homogeneous)
    imported = import_calibration([folder], SIZE)
    same_cameras(imported.calibration, truth)
    same_rectification(imported.calibration, truth)


def test_import_command_writes_a_calibration_the_tracker_reads(tmp_path, truth, capsys):
    write_storage(tmp_path / "intrinsics.yml", {"M1": truth.K1, "D1": truth.D1, "M2": truth.K2, "D2": truth.D2})
    write_storage(tmp_path / "extrinsics.yml", {"R": truth.R, "T": truth.T})
    out = tmp_path / "calib.yaml"
    assert main(["calibrate", "import", str(tmp_path / "intrinsics.yml"), str(tmp_path / "extrinsics.yml"),
                 "--image-size", "640x480", "-o", str(out)]) == 0
    assert "rectification computed" in capsys.readouterr().out
    same_cameras(load_calibration(out), truth)
    cv2.imwrite(str(tmp_path / "frame.png"), np.zeros((480, 640, 3), np.uint8))     # the size read from a frame
    assert main(["calibrate", "import", str(tmp_path / "intrinsics.yml"), str(tmp_path / "extrinsics.yml"),
                 "--frame", str(tmp_path / "frame.png"), "-o", str(tmp_path / "again.yaml")]) == 0
    same_cameras(load_calibration(tmp_path / "again.yaml"), truth)


def test_every_failing_loader_names_the_keys_found_and_expected(tmp_path, truth):
    write_storage(tmp_path / "intrinsics.yml", {"M1": truth.K1, "D1": truth.D1, "M2": truth.K2, "D2": truth.D2})
    with pytest.raises(CalibrationFileError) as caught:
        load_calibration(tmp_path / "intrinsics.yml")
    message = str(caught.value)
    assert "lacks image_width, image_height, K1, K2, R, T" in message and "it has M1, D1, M2, D2" in message
    assert "snreg calibrate import" in message and "recalibrate" not in message
    with pytest.raises(CalibrationFileError) as caught:
        import_calibration([tmp_path / "intrinsics.yml"], SIZE)
    assert "lacks R, T (found intrinsics.yml: M1, D1, M2, D2)" in str(caught.value)
    assert "recalibrate" not in str(caught.value)
    folder = tmp_path / "niftk"
    folder.mkdir()
    write_text(folder / "calib.left.intrinsics.txt", truth.K1)
    write_text(folder / "calib.left.distortion.txt", truth.D1)
    with pytest.raises(CalibrationFileError, match=r"lacks right intrinsics, right distortion, calib.r2l.rotation \+ "
                                                   r"calib.r2l.translation, or calib.l2r \(found calib.left.distortion.txt, "
                                                   r"calib.left.intrinsics.txt\)"):
        import_calibration([folder], SIZE)
    write_storage(tmp_path / "extrinsics.yml", {"R": truth.R, "T": truth.T})
    with pytest.raises(CalibrationFileError, match="do not give the image size; give it"):
        import_calibration([tmp_path / "intrinsics.yml", tmp_path / "extrinsics.yml"])


@pytest.mark.parametrize("change, message", [
    (lambda v: v.__setitem__("K1", np.diag([0.0, 536.0, 1.0])), "focal lengths must be positive"),
    (lambda v: v.__setitem__("T", np.array([np.nan, 0.0, 0.0])), "T holds NaN"),
    (lambda v: v.__setitem__("R", 2 * np.eye(3)), "R is not a rotation"),
    (lambda v: v.__setitem__("T", np.zeros(3)), "T is zero"),
    (lambda v: v.__setitem__("D1", np.zeros(3)), "D1 has 3 values"),
])
def test_a_calibration_that_cannot_be_right_is_refused(tmp_path, truth, change, message):
    values = {"image_width": SIZE[0], "image_height": SIZE[1], "K1": truth.K1, "D1": truth.D1, "K2": truth.K2,
              "D2": truth.D2, "R": truth.R, "T": truth.T}
    change(values)
    write_storage(tmp_path / "bad.yaml", values)
    with pytest.raises(CalibrationFileError, match=message):
        load_calibration(tmp_path / "bad.yaml")
