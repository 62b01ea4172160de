"""Every ``snreg`` command refuses bad input the same way: one line on stderr, exit status 2, no traceback,
nothing written (docs/design.md, Command line). The table holds the cases of issue 13 and more; they run
in-process through ``main(argv)``, a few through a real ``snreg`` process."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from snreg.camera import THESIS_CALIBRATION_PATH, StereoCalibration, save_calibration, thesis_calibration
from snreg.chain import ChainCalibration
from snreg.cli import main
from snreg.demo.spect import THESIS_SOURCES, THESIS_VOXEL_MM, spect_of_nodes, write_nm
from snreg.nodes import NodeSet, write_nodes
from snreg.session import Session

CALIB = str(THESIS_CALIBRATION_PATH)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Every input the table refers to, in one folder: ``{name}`` in an argv is replaced by its path."""
    d = tmp_path_factory.mktemp("inputs")
    rng = np.random.default_rng(13)
    xyz = rng.uniform(-60, 60, (6, 3))
    write_nodes(NodeSet([f"SN{k}" for k in range(6)], [""] * 6, xyz), d / "preop.csv")
    write_nodes(NodeSet([f"I{k}" for k in range(6)], [""] * 6, xyz + 2.0), d / "intraop.csv")
    write_nodes(NodeSet([f"N{k}" for k in range(300)], [""] * 300, rng.uniform(-200, 200, (300, 3))), d / "n300.csv")
    (d / "empty_id.csv").write_text("id,label,x,y,z\nSN1,,1,2,3\n,,4,5,6\nSN3,,7,8,9\n")
    (d / "bad_counts.csv").write_text("id,label,x,y,z,counts\nSN1,,1,2,3,12\nSN2,,4,5,6,lots\nSN3,,7,8,9,3\n")
    (d / "short_row.csv").write_text("id,label,x,y,z\nSN1,,1,2\nSN2,,4,5,6\nSN3,,7,8,9\n")
    (d / "huge.csv").write_text("id,label,x,y,z\nA,,1e308,0,0\nB,,0,1e308,0\nC,,0,0,1e308\nD,,1,1,1\n")
    (d / "ragged.mrk.json").write_text(json.dumps({"markups": [{"type": "Fiducial", "coordinateSystem": "LPS",
                                                                "controlPoints": [{"label": "A", "position": [1, 2, 3]},
                                                                                  {"label": "B", "position": [1, 2]}]}]}))
    (d / "initial_object.json").write_text(json.dumps({"rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}))
    (d / "initial_bottom.txt").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 1 0\n")
    (d / "initial_3x3.txt").write_text("1 0 0\n0 1 0\n0 0 1\n")
    (d / "existing.txt").write_text("keep me")
    (d / "folder").mkdir()
    truth = thesis_calibration()
    zero_focal = StereoCalibration(truth.image_size, np.diag([0.0, 0.0, 1.0]), truth.D1, truth.K2, truth.D2, truth.R,
                                   truth.T, truth.R1, truth.R2, truth.P1, truth.P2, truth.Q)
    save_calibration(zero_focal, d / "zero_focal.yaml")
    text = (Path(CALIB)).read_text()
    (d / "nan_T.yaml").write_text(text.replace("data: [ -4.3014683359121166, 0., 0. ]", "data: [ .nan, 0., 0. ]"))
    assert (d / "nan_T.yaml").read_text() != text
    (d / "only_K1.yaml").write_text("%YAML:1.0\n---\nK1: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
                                    "   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]\n")
    (d / "not_an_image.png").write_bytes(b"not an image")
    counts, origin = spect_of_nodes(THESIS_SOURCES, seed=5)
    write_nm(counts, origin, THESIS_VOXEL_MM, d / "phantom.dcm")
    data = (d / "phantom.dcm").read_bytes()
    (d / "truncated.dcm").write_bytes(data[:len(data) // 2])
    with Session.create(d / "session.h5", case_id="bad-input") as session:
        session.add_intraop_node("SN1", "OBT R", [1.0, 2.0, 3.0])
    (d / "imu_bad.csv").write_text("no,header\n1,2\n")
    (d / "imu1.csv").write_text("yaw,pitch,roll\n0,0,0\n")
    (d / "imu2.csv").write_text("yaw,pitch,roll\n0,0,0\n1,0,0\n")
    (d / "chain.json").write_text(json.dumps(ChainCalibration.manual().to_dict()))
    (d / "bad_chain.json").write_text("{")
    (d / "list_chain.json").write_text("[1, 2]")
    save_calibration(truth.scaled(0.5), d / "half.yaml")
    _hostile(d, text, truth)
    return d


def _hostile(d: Path, text: str, truth: StereoCalibration) -> None:
    """Issue 21's inputs: special files, other separators, degenerate node sets, broken calibrations and DICOM."""
    import cv2
    import pydicom

    os.mkfifo(d / "fifo.csv")
    os.mkfifo(d / "fifo.h5")
    (d / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    (d / "semicolon.csv").write_text("id;label;x;y;z\nA;;1;2;3\nB;;4;5;6\nC;;7;8;10\n")
    (d / "collinear.csv").write_text("id,label,x,y,z\nA,,0,0,0\nB,,10,0,0\nC,,20,0,0\nD,,35,0,0\n")
    (d / "coincident.csv").write_text("id,label,x,y,z\nA,,1,2,3\nB,,1,2,3\nC,,1,2,3\n")
    (d / "header_only.yaml").write_text("%YAML:1.0\n")
    (d / "short_data.yaml").write_text(text.replace("data: [ 0., 0., 0., 0., 0. ]", "data: [ 0., 0. ]", 1))
    (d / "cut.yaml").write_text(text[:text.index("data", 300) + 20])
    (d / "wide.yaml").write_text(text.replace("image_width: 1920", "image_width: 1000000000"))
    (d / "nan_width.yaml").write_text(text.replace("image_width: 1920", "image_width: .Nan"))
    (d / "abc_width.yaml").write_text(text.replace("image_width: 1920", 'image_width: "abc"'))
    (d / "far_T.yaml").write_text(text.replace("data: [ -4.3014683359121166, 0., 0. ]", "data: [ -1e200, 0., 0. ]"))
    (d / "deep.yaml").write_text("%YAML:1.0\na: " + "[" * 50_000 + "]" * 50_000 + "\n")
    for name, key, value in (("zero_Q", "Q", np.zeros((4, 4))), ("zero_P1", "P1", np.zeros((3, 4))),
                             ("vertical_T", "T", np.array([[0.0], [-4.3], [0.0]]))):
        fs = cv2.FileStorage(str(d / f"{name}.yaml"), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", 1920)
        fs.write("image_height", 1080)
        for k in ("K1", "D1", "K2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q"):
            fs.write(k, value if k == key else np.asarray(getattr(truth, k), dtype=float))
        fs.release()
    for name, attribute, value in (("iop3", "ImageOrientationPatient", [1, 0, 0]),
                                   ("iop_zero", "ImageOrientationPatient", [0] * 6),
                                   ("iop_parallel", "ImageOrientationPatient", [1, 0, 0, 1, 0, 0]),
                                   ("spacing1", "PixelSpacing", [4.8]), ("spacing0", "PixelSpacing", [0, 0])):
        ds = pydicom.dcmread(d / "phantom.dcm")
        where = ds.DetectorInformationSequence[0] if attribute == "ImageOrientationPatient" else ds
        setattr(where, attribute, value)
        ds.save_as(d / f"{name}.dcm", enforce_file_format=False)


MISSING = "/nonexistent-folder-13"

# (argv with {name} for a file of the fixture, a fragment the one stderr line must hold)
CASES = [
    # the command line itself
    ([], "COMMAND"),
    (["frobnicate"], "invalid choice"),
    (["calibrate"], "WHAT"),
    (["session"], "ACTION"),
    (["register"], "required"),
    # register
    (["register", "{preop.csv}", "{intraop.csv}", "--initial", "{initial_object.json}"], '"transform"'),
    (["register", "{preop.csv}", "{intraop.csv}", "--initial", "{initial_bottom.txt}"], "0 0 0 1"),
    (["register", "{preop.csv}", "{intraop.csv}", "--initial", "{initial_3x3.txt}"], "4x4"),
    (["register", "{preop.csv}", "{intraop.csv}", "--initial", "{missing.txt}"], "no such initial transform file"),
    (["register", "{preop.csv}", "{intraop.csv}", "--initial", "{deep.json}"], "not a matrix of numbers"),
    (["register", "{preop.csv}", "{intraop.csv}", "--initial", "/dev/zero"], "not a regular file"),
    (["register", "{preop.csv}", "{fifo.csv}"], "not a regular file"),
    (["register", "{preop.csv}", "/dev/zero"], "not a regular file"),
    (["register", "{preop.csv}", "{semicolon.csv}"], "separated by semicolons"),
    (["register", "{preop.csv}", "{collinear.csv}"], "intraop nodes are collinear"),
    (["register", "{coincident.csv}", "{intraop.csv}"], "preop nodes coincide"),
    (["register", "{fifo.h5}"], "not a regular file"),
    (["register", "{preop.csv}", "{intraop.csv}", "-o", MISSING + "/result.json"], "does not exist"),
    (["register", "{preop.csv}", "{intraop.csv}", "-o", "{folder}"], "is a folder"),
    (["register", "{n300.csv}", "{intraop.csv}"], "at most 50"),
    (["register", "{preop.csv}", "{n300.csv}"], "at most 50"),
    (["register", "{missing.csv}", "{intraop.csv}"], "no such node file"),
    (["register", "{folder}", "{intraop.csv}"], "is a folder"),
    (["register", "{preop.csv}", "{empty_id.csv}"], "empty id"),
    (["register", "{preop.csv}", "{bad_counts.csv}"], "counts that are not a number"),
    (["register", "{preop.csv}", "{huge.csv}"], "1e+05"),
    (["register", "{preop.csv}", "{ragged.mrk.json}"], "ragged.mrk.json"),
    (["register", "{preop.csv}", "{short_row.csv}"], "data row 1 (line 2) has 4 fields"),
    (["register", "{preop.csv}", "{intraop.csv}", "--method", "best"], "--method"),
    (["register", "{preop.csv}", "{intraop.csv}", "--seed", "-1"], "--seed"),
    (["register", "{preop.csv}", "{intraop.csv}", "--max-rotation", "nan"], "--max-rotation"),
    (["register", "{preop.csv}", "{intraop.csv}", "--down-preop", "0,0,0"], "--down-preop"),
    (["register", "{preop.csv}", "{intraop.csv}", "--down-intraop", "1,inf,0"], "--down-intraop"),
    (["register", "{preop.csv}", "{intraop.csv}", "--tilt", "75"], "from 0 to 60 degrees"),
    (["register", "{preop.csv}", "{intraop.csv}", "--tilt", "20"], "records no patient position"),
    # track-camera
    (["track-camera", "--left", "{l.png}", "--right", "{r.png}", "--imu-csv", "{imu1.csv}", "--calib", CALIB,
      "--chain", "{missing.json}"], "missing.json"),
    (["track-camera", "--left", "{l.png}", "--right", "{r.png}", "--imu-csv", "{imu1.csv}", "--calib", CALIB,
      "--chain", "{bad_chain.json}"], "not a chain file"),
    (["track-camera", "--left", "{l.png}", "--right", "{r.png}", "--imu-csv", "{imu1.csv}", "--calib", CALIB,
      "--chain", "{list_chain.json}"], "expected a JSON object"),
    (["track-camera", "--left", "{l.png}", "--right", "{r.png}", "--imu-csv", "{imu1.csv}", "--calib", CALIB,
      "--chain", "{preop.csv}"], "not a chain file"),
    (["track-camera", "--left", "{l.png}", "--right", "{r.png}", "--imu-csv", "{imu2.csv}", "--calib", CALIB,
      "--chain", "{chain.json}"], "2 IMU rows for 1 pairs"),
    (["track-camera", "--left", "{l.png}", "--right", "{r.png}", "--imu-csv", "{imu_bad.csv}", "--calib", CALIB,
      "--chain", "{chain.json}"], "yaw,pitch,roll"),
    (["track-camera", "--left", "{l.png}", "--right", "{missing.png}", "--imu-csv", "{imu1.csv}", "--calib", CALIB,
      "--chain", "{chain.json}"], "No right images"),
    (["track-camera", "--left", "{l.png}", "--right", "{r.png}", "--imu-csv", "{imu1.csv}", "--calib", "{half.yaml}",
      "--chain", "{chain.json}"], "the calibration is for 960x540"),
    (["track-camera", "--left", "{l.png}", "--right", "{r.png}", "--imu-csv", "{imu1.csv}", "--calib", CALIB],
     "--chain"),
    # calibrate trocar tissue
    (["calibrate", "trocar", "tissue", "--left", "{l.png}", "--right", "{missing.png}", "--calib", CALIB],
     "No right images"),
    (["calibrate", "trocar", "tissue", "--left", "{l.png}", "--right", "{r.png}", "--calib", "{half.yaml}"],
     "the calibration is for 960x540"),
    (["calibrate", "trocar", "tissue", "--left", "{l.png}", "--right", "{r.png}", "--calib", CALIB,
      "--imu-csv", "{imu2.csv}"], "2 IMU rows for 1 pairs"),
    (["calibrate", "trocar", "tissue", "--left", "{l.png}", "--right", "{r.png}", "--calib", CALIB],
     "found in only 0 of 1 pairs"),
    (["calibrate", "trocar", "tissue", "--left", "{l.png}", "--right", "{r.png}", "--calib", CALIB, "-o",
      MISSING + "/chain.json"], "does not exist"),
    (["calibrate", "trocar", "tissue", "--left", "{l.png}", "--right", "{r.png}"], "--calib"),
    # simulate
    (["simulate", "--sigmas", "-5"], "--sigmas"),
    (["simulate", "--sigmas", "nan"], "--sigmas"),
    (["simulate", "--methods", "foo"], "foo"),
    (["simulate", "--methods", "cpd:w=abc"], "cpd:w=abc"),
    (["simulate", "--methods", "cpd:w=2"], "cpd:w=2"),
    (["simulate", "--workers", "-1"], "--workers"),
    (["simulate", "--workers", "100000"], "this machine has"),
    (["simulate", "--reps", "99999999999999999999"], "--reps"),
    (["simulate", "--sigmas", "1e308"], "--sigmas"),
    (["simulate", "--missing", "100", "--methods", "icp", "-o", "{sim}"], "--missing 100"),
    (["simulate", "--reps", "0"], "--reps"),
    (["budget", "--workers", "100000"], "this machine has"),
    (["budget", "--reps", "99999999999999999999"], "--reps"),
    (["budget", "--errors", "{deep.json}"], "nested 100000 levels deep"),
    (["budget", "--errors", "{fifo.csv}"], "not a regular file"),
    (["budget", "--errors", "{header_only.yaml}"], "not an OpenCV error model file"),
    (["demo", "--headless", "--errors", "{deep.json}", "-o", "{demo.h5}"], "nested 100000 levels deep"),
    (["demo", "--headless", "--camera", "moving", "-o", "{demo.h5}"], "--camera"),
    (["demo", "--headless", "--no-camera-tracking", "-o", "{demo.h5}"], "applies to --camera surgery"),
    (["session", "verify", "{fifo.h5}"], "not a regular file"),
    (["session", "retrack", "{fifo.h5}"], "not a regular file"),
    (["simulate", "--extras", "-1"], "--extras"),
    (["simulate", "-o", "{existing.txt}"], "is a file, not a folder"),
    (["simulate", "-o", MISSING + "/report"], "does not exist"),
    (["simulate", "--seed", "99999999999"], "--seed"),
    # track
    (["track", "{l.png}", "{r.png}", "--calib", "{zero_focal.yaml}"], "focal lengths must be positive"),
    (["track", "{l.png}", "{r.png}", "--calib", "{nan_T.yaml}"], "NaN"),
    (["track", "{l.png}", "{r.png}", "--calib", "{only_K1.yaml}"], "image_width"),
    (["track", "{l.png}", "{r.png}", "--calib", "{missing.yaml}"], "no such calibration"),
    (["track", "{l.png}", "{r.png}", "--calib", "{header_only.yaml}"], "holds no keys"),
    (["track", "{l.png}", "{r.png}", "--calib", "{short_data.yaml}"], "more or fewer values than rows x cols"),
    (["track", "{l.png}", "{r.png}", "--calib", "{cut.yaml}"], "not an OpenCV calibration file"),
    (["track", "{l.png}", "{r.png}", "--calib", "{wide.yaml}"], "beyond any camera"),
    (["track", "{l.png}", "{r.png}", "--calib", "{nan_width.yaml}"], "positive whole numbers"),
    (["track", "{l.png}", "{r.png}", "--calib", "{abc_width.yaml}"], "image_width is the text 'abc'"),
    (["track", "{l.png}", "{r.png}", "--calib", "{far_T.yaml}"], "check T's units"),
    (["track", "{l.png}", "{r.png}", "--calib", "{deep.yaml}"], "nested"),
    (["track", "{l.png}", "{r.png}", "--calib", "{zero_Q.yaml}"], "Q does not follow from P1 and P2"),
    (["track", "{l.png}", "{r.png}", "--calib", "{zero_P1.yaml}"], "P1 is not a rectified projection"),
    (["track", "{l.png}", "{r.png}", "--calib", "{vertical_T.yaml}"], "P2 does not hold the vertical baseline"),
    (["track", "{not_an_image.png}", "{not_an_image.png}", "--calib", CALIB], "not a readable image"),
    (["track", "{missing.png}", "{missing.png}", "--calib", CALIB], "missing.png"),
    (["track", "{l.png}", "{r.png}", "--calib", CALIB, "--method", "laser"], "--method"),
    (["track", "{l.png}", "{r.png}", "--calib", CALIB, "--depth-range", "300,20"], "--depth-range"),
    (["track", "{l.png}", "{r.png}", "--calib", CALIB, "--depth-range", "near"], "--depth-range"),
    # calibrate stereo, import, check, trocar
    (["calibrate", "stereo", "--left", "{none*.png}", "--right", "{none*.png}", "--board", "9x6", "--square", "1",
      "-o", "{c.yaml}"], "no files match"),
    (["calibrate", "stereo", "--left", "{none*.png}", "--right", "{none*.png}", "--board", "9x6", "--square", "1",
      "-o", MISSING + "/c.yaml"], "does not exist"),
    (["calibrate", "stereo", "--left", "a", "--right", "b", "--board", "9x6", "--square", "-1", "-o", "c.yaml"], "--square"),
    (["calibrate", "stereo", "--left", "a", "--right", "b", "--board", "9x6", "--square", "1", "-o", "{c.yaml}",
      "--drop", "x"], "--drop"),
    (["calibrate", "import", "{only_K1.yaml}", "--image-size", "640x480", "-o", "{c.yaml}"], "lacks D1"),
    (["calibrate", "import", "{folder}", "--image-size", "640x480", "-o", "{c.yaml}"], "no files"),
    (["calibrate", "import", "{missing.yml}", "--image-size", "640x480", "-o", "{c.yaml}"], "no such file"),
    (["calibrate", "import", "{only_K1.yaml}", "--image-size", "640by480", "-o", "{c.yaml}"], "--image-size"),
    (["calibrate", "import", "{only_K1.yaml}", "--image-size", "0x480", "-o", "{c.yaml}"], "--image-size"),
    (["calibrate", "import", "{only_K1.yaml}", "--frame", "{not_an_image.png}", "-o", "{c.yaml}"], "--frame"),
    (["calibrate", "import", "{only_K1.yaml}", "--image-size", "640x480", "-o", MISSING + "/c.yaml"], "does not exist"),
    (["calibrate", "check", "{missing.yaml}", "--left", "{l.png}", "--right", "{r.png}", "--board", "9x6",
      "--square", "1"], "no such calibration"),
    (["calibrate", "check", CALIB, "--left", "{l.png}", "--right", "{r.png}", "--board", "9by6", "--square", "1"],
     "COLSxROWS"),
    (["calibrate", "check", CALIB, "--left", "{l.png}", "--right", "{r.png}", "--board", "9x6", "--square", "1"],
     "found in no pair"),
    (["calibrate", "trocar", "manual", "--imu-trocar", "nan", "--trocar-camera", "158"], "--imu-trocar"),
    (["calibrate", "trocar", "manual", "--imu-trocar", "460", "--trocar-camera", "-5"], "positive"),
    (["calibrate", "trocar", "manual", "--imu-trocar", "1e308", "--trocar-camera", "158"], "at most 5000 mm"),
    (["calibrate", "trocar", "manual", "--imu-trocar", "460", "--trocar-camera", "158", "-o", MISSING + "/chain.json"],
     "does not exist"),
    (["calibrate", "trocar", "pivot", "--images", "{none*.png}", "--board", "9x6", "--square", "10", "--calib", CALIB],
     "no files match"),
    (["calibrate", "trocar", "pivot", "--images", "{l.png}", "--board", "9x6", "--square", "10", "--calib", CALIB,
      "--imu-csv", "{imu_bad.csv}"], "yaw,pitch,roll"),
    # preop
    (["preop", "{phantom.dcm}", "-o", "{nodes.csv}", "--midline-x", "nan"], "--midline-x"),
    (["preop", "{phantom.dcm}", "-o", "{nodes.csv}", "--midline-x", "inf"], "--midline-x"),
    (["preop", "{phantom.dcm}", "-o", "{nodes.csv}", "--nodes", "50"], "ask for at most"),
    (["preop", "{phantom.dcm}", "-o", "{nodes.csv}", "--nodes", "1000"], "at most 100"),
    (["preop", "{phantom.dcm}", "-o", "{nodes.csv}", "--nodes", "0"], "--nodes"),
    (["preop", "{phantom.dcm}", "-o", "{x.h5}"], ".csv or .mrk.json"),
    (["preop", "{phantom.dcm}", "-o", "{nodes.csv}", "--threshold", "1.5"], "between 0 and 1"),
    (["preop", "{phantom.dcm}", "-o", "{nodes.csv}", "--tilt", "-3"], "--tilt"),
    (["preop", "{truncated.dcm}", "-o", "{nodes.csv}"], "truncated"),
    (["preop", "{phantom.dcm}", "-o", "{nodes.csv}", "--threshold", "1e-300"], "raise --threshold"),
    (["preop", "{iop3.dcm}", "-o", "{nodes.csv}"], "ImageOrientationPatient has 3 value(s)"),
    (["preop", "{iop_zero.dcm}", "-o", "{nodes.csv}"], "not two unit vectors"),
    (["preop", "{iop_parallel.dcm}", "-o", "{nodes.csv}"], "not perpendicular"),
    (["preop", "{spacing1.dcm}", "-o", "{nodes.csv}"], "PixelSpacing has 1 value(s)"),
    (["preop", "{spacing0.dcm}", "-o", "{nodes.csv}"], "is not a voxel size"),
    (["preop", "/dev/zero", "-o", "{nodes.csv}"], "not a regular file"),
    (["preop", "{missing.dcm}", "-o", "{nodes.csv}"], "does not exist"),
    (["preop", "{phantom.dcm}", "-o", MISSING + "/nodes.csv"], "does not exist"),
    # session
    (["session", "info", "{missing.h5}"], "missing.h5"),
    (["session", "info", "{existing.txt}"], "existing.txt"),
    (["session", "export", "{session.h5}", "-o", MISSING + "/nodes.csv"], "does not exist"),
    (["session", "export", "{session.h5}", "-o", "{folder}"], "is a folder"),
    (["session", "export", "{session.h5}", "--format", "xml", "-o", "{nodes.csv}"], "--format"),
    (["session", "recover", "{session.h5}", "-o", "{existing.txt}"], "already exists"),
    (["session", "recover", "{session.h5}", "-o", MISSING + "/s.h5"], "does not exist"),
    # imu
    (["imu", "simulate", "--parent", "999999"], "--parent 999999"),
    (["imu", "simulate", "--parent", "-1"], "--parent"),
    (["imu", "simulate", "--rate", "0"], "--rate"),
    (["imu", "simulate", "--attitude", "0,10,20"], "with --still"),
    (["imu", "simulate", "--still", "--attitude", "0,10"], "three numbers"),
    (["imu", "simulate", "--rate", "1e12"], "--rate"),
    (["imu", "simulate", "--rate", "1e-9"], "--rate"),
    (["imu", "monitor", "/dev/null", "--seconds", "1e308"], "--seconds"),
    (["imu", "simulate", "--dropout", "2"], "--dropout"),
    (["imu", "monitor", "/dev/null", "--csv", MISSING + "/imu.csv"], "does not exist"),
    (["imu", "monitor", "/dev/null", "--baud", "fast"], "--baud"),
    # demo, bench, experiments
    (["demo", "-o", "{demo.h5}"], "--headless"),
    (["demo", "--headless", "-o", MISSING + "/demo.h5"], "does not exist"),
    (["demo", "--headless", "-o", "{existing.txt}"], "already exists"),
    (["demo", "--headless", "-o", "{demo.h5}", "--fixes", "0"], "--fixes"),
    (["demo", "--headless", "-o", "{demo.h5}", "--fixes", "1000000000"], "--fixes"),
    (["demo", "--headless", "-o", "{demo.h5}", "--igtl", "99999"], "--igtl"),
    (["demo", "--headless", "-o", "{demo.h5}", "--seed", "-1"], "--seed"),
    (["bench", "--pairs", "0"], "--pairs"),
    (["bench", "--reps", "-2"], "--reps"),
    (["experiment", "tracking", "--frames", "1"], "--frames"),
    (["experiment", "tracking", "--noise", "-1"], "--noise"),
    (["experiment", "imu", "--seed", "x"], "--seed"),
]


def expand(argv: list[str], folder: Path) -> list[str]:
    """Each ``{name}`` becomes ``folder/name``."""
    return [str(folder / a[1:-1]) if a.startswith("{") and a.endswith("}") else a for a in argv]


def run(argv: list[str], capsys) -> tuple[int, str, str]:
    try:
        status = main(argv)
    except SystemExit as stop:              # argparse's own errors end here, as they do on the command line
        status = stop.code
    out, err = capsys.readouterr()
    return status, out, err


@pytest.fixture(scope="module")
def images(files):
    """``l.png``/``r.png``: a grey 1920x1080 pair (no probe, no board), the thesis calibration's size."""
    import cv2

    for name in ("l.png", "r.png"):
        cv2.imwrite(str(files / name), np.full((1080, 1920, 3), 90, np.uint8))
    return files


def test_the_table_is_large_enough():
    assert len(CASES) >= 60


@pytest.mark.parametrize("argv, fragment", CASES, ids=[" ".join(a)[:60] or "(none)" for a, _ in CASES])
def test_bad_input_is_one_stderr_line_and_exit_2(images, argv, fragment, capsys):
    before = sorted(p.name for p in images.iterdir())
    status, out, err = run(expand(argv, images), capsys)
    assert status == 2, (status, out, err)
    assert err.endswith("\n") and err.count("\n") == 1 and err.startswith("snreg"), err
    assert "Traceback" not in err and fragment in err, err
    assert sorted(p.name for p in images.iterdir()) == before, "something was written"
    assert (images / "existing.txt").read_text() == "keep me"


def test_a_pivot_recording_judged_bad_exits_2_and_writes_no_chain(tmp_path, capsys):
    """Images that are not a pivot recording (OpenCV's stereo samples, the board moved about) printed a
    chain with exit status 0 before."""
    samples = Path(__file__).resolve().parent / "data" / "stereo_calib"
    K = np.array([[530.0, 0, 320], [0, 530, 240], [0, 0, 1]])
    save_calibration(StereoCalibration.from_pair((640, 480), K, np.zeros(5), K, np.zeros(5), np.eye(3), [-3.3, 0, 0]),
                     tmp_path / "c.yaml")
    status, out, err = run(["calibrate", "trocar", "pivot", "--images", str(samples / "left*.jpg"), "--board", "9x6",
                            "--square", "25", "--calib", str(tmp_path / "c.yaml"), "-o", str(tmp_path / "chain.json")],
                           capsys)
    assert status == 2 and "verdict: bad" in out and err.count("\n") == 1
    assert "pivot calibration refused" in err and "no chain file written" in err
    assert not (tmp_path / "chain.json").exists()


def test_node_csv_with_a_byte_order_mark_reads(files, tmp_path, capsys):
    text = (files / "intraop.csv").read_text(encoding="utf-8")
    (tmp_path / "excel.csv").write_bytes("\ufeff".encode("utf-8") + text.encode("utf-8"))
    status, out, _ = run(["register", str(files / "preop.csv"), str(tmp_path / "excel.csv"), "--method", "icp",
                          "--json"], capsys)
    assert status == 0 and len(json.loads(out)["nodes"]) == 6


def test_a_failed_write_leaves_the_previous_file(files, tmp_path, capsys, monkeypatch):
    """A write that fails half-way (a full disk) keeps the previous file whole and leaves no fragment."""
    import snreg.files

    out = tmp_path / "chain.json"
    out.write_text("previous")

    def full_disk(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(snreg.files.os, "replace", full_disk)
    status, _, err = run(["calibrate", "trocar", "manual", "--imu-trocar", "460", "--trocar-camera", "158", "-o",
                          str(out)], capsys)
    assert status == 2 and "No space left on device" in err and err.count("\n") == 1
    assert out.read_text() == "previous" and sorted(p.name for p in tmp_path.iterdir()) == ["chain.json"]


def snreg_process(*argv, **kwargs) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    streams = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, **kwargs}
    return subprocess.run([sys.executable, "-m", "snreg.cli", *argv], text=True, env=env, timeout=120, **streams)


@pytest.mark.parametrize("argv, fragment", [
    (["register", "{preop.csv}", "{intraop.csv}", "--initial", "{initial_object.json}"], '"transform"'),
    (["simulate", "--sigmas", "nan"], "--sigmas"),
    (["track", "{l.png}", "{r.png}", "--calib", "{nan_T.yaml}"], "NaN"),
    (["imu", "simulate", "--parent", "999999"], "--parent"),
    (["track", "{not_an_image.png}", "{r.png}", "--calib", CALIB], "not a readable image"),   # no OpenCV log line
])
@pytest.mark.slow
def test_bad_input_through_a_real_process(images, argv, fragment):
    result = snreg_process(*expand(argv, images))
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.count("\n") == 1 and fragment in result.stderr and "Traceback" not in result.stderr


def test_a_full_stdout_is_one_line_and_a_closed_pipe_is_quiet():
    with open("/dev/full", "w") as full:
        result = snreg_process("calibrate", "trocar", "manual", "--imu-trocar", "460", "--trocar-camera", "158",
                               stdout=full)
    assert result.returncode == 2 and result.stderr == "snreg: cannot write the output (No space left on device)\n"
    writer = subprocess.Popen([sys.executable, "-m", "snreg.cli", "calibrate", "trocar", "manual", "--imu-trocar", "460",
                               "--trocar-camera", "158"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    writer.stdout.close()                        # the reader went away (snreg ... | head) before the output came
    assert writer.stderr.read() == b"" and writer.wait(timeout=60) == 1


def test_building_the_parser_imports_nothing_heavy():
    """``snreg --help`` stays fast because no subcommand's dependencies load until it runs."""
    code = ("import sys; from snreg.cli import build_parser; build_parser().format_help(); "
            "print(sorted(m for m in ('numpy', 'cv2', 'scipy', 'h5py', 'pydicom', 'serial', 'matplotlib') "
            "if m in sys.modules))")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                            env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    assert result.stdout.strip() == "[]", result.stderr


def test_defaults_stated_in_the_cli_match_the_library():
    """The CLI states a few library defaults itself so that building the parser imports no numpy."""
    from snreg.chain import THESIS_IMU_TROCAR_MM
    from snreg.cli import imu, register, simulate, track, trocar
    from snreg.imu.reader import DEFAULT_BAUD
    from snreg.probe import default_probe_model
    from snreg.registration import METHODS
    from snreg.simulation import study

    assert imu.DEFAULT_BAUD == DEFAULT_BAUD and trocar.THESIS_IMU_TROCAR_MM == THESIS_IMU_TROCAR_MM
    assert register.METHOD_CHOICES == METHODS and track.DEFAULT_DEPTH_RANGE_MM == default_probe_model().working_range_mm
    assert simulate.DEFAULTS == {"reps": study.DEFAULT_REPS, "sigmas": study.DEFAULT_SIGMAS,
                                 "extras": study.DEFAULT_EXTRAS, "methods": study.DEFAULT_METHODS}


def test_help_shows_the_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "(default: 25)" in text and "(default: 2,5,10,15,20)" in text


def test_a_calibration_written_to_a_full_device_raises_instead_of_reporting_success():
    """``calibrate stereo -o /dev/full`` printed "wrote" with a 0-byte file; the write error now surfaces."""
    with pytest.raises(OSError):
        save_calibration(thesis_calibration(), "/dev/full")
