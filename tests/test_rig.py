"""The hardware rig on rendered frames (image folders, video files standing in for cameras), a simulated IMU on a pty."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from conftest import poll

from snreg.calibration.checkerboard import THESIS_BOARD, find_corners
from snreg.camera import CalibrationFileError, save_calibration, thesis_calibration
from snreg.chain import ChainCalibration
from snreg.demo.imu_motion import MotionProfile, still
from snreg.demo.imu_simulator import ImuSimulator, SimulatedPort
from snreg.demo.pivot_scene import SceneImu
from snreg.demo.renderer import ProbePose, StereoRenderer
from snreg.demo.rig import DemoRig
from snreg.imu import monitor
from snreg.probe import default_probe_model, save_probe_model
from snreg.rig import ABSENT, AbsentImu, HardwareRig, Imu, Rig, RigConfig, check_source
from snreg.sources import SourceState

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)

SCALE = 0.25                         # the thesis cameras at 480x270
N_PAIRS = 3


def assert_sentence(message: str) -> None:
    assert "\n" not in message and "Traceback" not in message
    assert message[:1].isupper() and message.endswith(".")


def write_video(path, images) -> str:
    height, width = images[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (width, height))
    assert writer.isOpened()
    for image in images:
        writer.write(image)
    writer.release()
    return str(path)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """Rendered pairs as image folders and video files, the matching calibration and one at twice the size."""
    root = tmp_path_factory.mktemp("rig")
    calibration = thesis_calibration().scaled(SCALE)
    renderer = StereoRenderer(calibration, default_probe_model())
    pairs = [renderer.render(ProbePose.make([5.0 * k, 0.0, 90.0], [0.2, -0.3, -1.0])) for k in range(N_PAIRS)]
    for k, (left, right) in enumerate(pairs):
        cv2.imwrite(str(root / f"left_{k}.png"), left)
        cv2.imwrite(str(root / f"right_{k}.png"), right)
    save_calibration(calibration, root / "calib.yaml")
    save_calibration(thesis_calibration().scaled(2 * SCALE), root / "calib_960.yaml")
    videos = {"left": write_video(root / "left.avi", [p[0] for p in pairs]),
              "right": write_video(root / "right.avi", [p[1] for p in pairs]),
              "side_by_side": write_video(root / "sbs.avi", [np.hstack(p) for p in pairs]),
              "top_bottom": write_video(root / "tb.avi", [np.vstack(p) for p in pairs])}
    return root, pairs, videos


def folder_config(root, **changes) -> RigConfig:
    values = dict(mode="folder", left=str(root / "left_*.png"), right=str(root / "right_*.png"),
                  calibration_path=str(root / "calib.yaml"), fps=25.0)
    return RigConfig(**(values | changes))


@pytest.fixture
def imu_port(tmp_path):
    """A simulated IMU, still and level, on a real pseudo-terminal behind a link (as 'snreg imu simulate' makes)."""
    port = SimulatedPort(ImuSimulator(MotionProfile([still(1.0)]), seed=4), port_link=str(tmp_path / "imu")).start()
    yield port
    port.stop()


@pytest.mark.slow
def test_folder_rig_reads_the_recorded_pairs_and_the_imu_streams(recording, imu_port):
    root, pairs, _ = recording
    rig = HardwareRig(folder_config(root, serial_port=imu_port.port))
    try:
        assert rig.calibration.image_size == (480, 270) and rig.fps == 25.0
        assert rig.probe == default_probe_model()
        assert rig.chain.trocar_camera_mm == pytest.approx(ChainCalibration.manual().trocar_camera_mm)
        source = rig.frame_source()
        frames = list(source)
        assert len(frames) == N_PAIRS and source.state is SourceState.ENDED
        for frame, (left, right) in zip(frames, pairs):
            np.testing.assert_array_equal(frame.left, left)
            np.testing.assert_array_equal(frame.right, right)
        assert [f.t_left_ns for f in frames] == [round(k * 1e9 / 25.0) for k in range(N_PAIRS)]
        assert poll(lambda: rig.imu.snapshot().samples >= 50)
        snapshot = rig.imu.snapshot()
        assert snapshot.state == "streaming" and snapshot.corrupt == 0
        assert np.degrees(np.arccos(np.clip(snapshot.earth_from_imu[2, 2], -1, 1))) < 2.0     # level: z up
        assert len(rig.imu.take_samples()) >= 50
    finally:
        rig.close()
    assert rig.imu.snapshot().state == "stopped"


def test_the_rig_uses_the_given_chain_the_chosen_probe_model_and_baud_rate(recording, imu_port, monkeypatch, tmp_path):
    root, _, _ = recording
    probe = replace(default_probe_model(), diameter_mm=12.0, stripe_centres_mm=(15.0, 25.0, 35.0))
    save_probe_model(probe, tmp_path / "probe.yaml")
    opened = []

    class RecordingReader(monitor.SerialImuReader):
        def __init__(self, port, baudrate, **kwargs):
            opened.append((port, baudrate))
            super().__init__(port, baudrate, **kwargs)

    monkeypatch.setattr(monitor, "SerialImuReader", RecordingReader)
    chain = ChainCalibration.manual(imu_trocar_mm=300.0, trocar_camera_mm=120.0)
    rig = HardwareRig(folder_config(root, serial_port=imu_port.port, baudrate=115200,
                                    probe_path=str(tmp_path / "probe.yaml")), chain=chain)
    rig.close()
    assert rig.chain is chain and opened == [(imu_port.port, 115200)]
    assert rig.probe == probe


@pytest.mark.parametrize("mode, layout", [("pair", "side_by_side"), ("video", "side_by_side"),
                                          ("stacked", "side_by_side"), ("stacked", "top_bottom")])
def test_every_camera_mode_delivers_the_eyes_in_order(recording, mode, layout):
    """Video files stand in for devices (OpenCV opens a path like a camera); MJPG is lossy, hence the tolerance."""
    root, pairs, videos = recording
    config = RigConfig(mode=mode, left=videos["left"], right=videos["right"], device=videos.get(layout, ""),
                       layout=layout, calibration_path=str(root / "calib.yaml"))
    assert check_source(config) == (480, 270)
    rig = HardwareRig(config)
    source = rig.frame_source()
    try:
        frame = source.read()
        for got, want, other in ((frame.left, pairs[0][0], pairs[0][1]), (frame.right, pairs[0][1], pairs[0][0])):
            error = np.abs(got.astype(float) - want).mean()
            assert error < 3.0 and error < np.abs(got.astype(float) - other).mean()
    finally:
        source.close()
        rig.close()


def test_a_calibration_of_another_size_is_refused_in_one_sentence(recording):
    root, _, _ = recording
    config = folder_config(root, calibration_path=str(root / "calib_960.yaml"))
    rig = HardwareRig(config)
    with pytest.raises(ValueError, match=r"480x270 per eye .* for 960x540") as err:
        rig.frame_source()
    assert_sentence(str(err.value))
    with pytest.raises(ValueError, match="480x270 per eye"):
        check_source(config)
    rig.close()


def test_a_requested_camera_size_that_does_not_fit_the_calibration_is_refused_before_opening(recording):
    root, _, _ = recording
    config = RigConfig(mode="stacked", device="/dev/video-none", frame_size=(960, 540),
                       calibration_path=str(root / "calib.yaml"))
    with pytest.raises(ValueError, match=r"480x540 per eye .* for 480x270") as err:
        HardwareRig(config)
    assert_sentence(str(err.value))


def test_missing_files_and_ports_are_one_sentence_errors(recording, tmp_path):
    root, _, _ = recording
    with pytest.raises(ValueError, match="does not exist") as err:
        HardwareRig(folder_config(root, serial_port=str(tmp_path / "ttyACM7")))
    assert_sentence(str(err.value))
    with pytest.raises(ValueError, match="Cannot open the IMU port COM7") as err:
        HardwareRig(folder_config(root, serial_port="COM7"))
    assert_sentence(str(err.value))
    with pytest.raises(CalibrationFileError, match="no such calibration file"):
        HardwareRig(folder_config(root, calibration_path=str(tmp_path / "none.yaml")))
    with pytest.raises(ValueError, match="Choose the stereo calibration file"):
        HardwareRig(folder_config(root, calibration_path=""))
    with pytest.raises(ValueError, match="No left images match"):
        check_source(folder_config(root, left=str(tmp_path / "*.png")))
    with pytest.raises(ValueError, match="Choose the right image pattern"):
        check_source(folder_config(root, right=""))


def test_without_a_port_the_imu_is_absent_and_level(recording):
    root, _, _ = recording
    rig = HardwareRig(folder_config(root))
    assert isinstance(rig.imu, AbsentImu)
    snapshot = rig.imu.snapshot()
    assert snapshot.state == ABSENT and not snapshot.stale and snapshot.samples == 0
    assert snapshot.euler_deg == (0.0, 0.0, 0.0)
    np.testing.assert_array_equal(snapshot.earth_from_imu, np.eye(3))
    assert "no IMU port was chosen" in snapshot.problem and rig.imu.take_samples() == []
    rig.close()


def test_config_round_trips_through_a_plain_dict_and_json():
    config = RigConfig(mode="stacked", device="0", layout="top_bottom", frame_size=(1920, 2160), fps=60,
                       serial_port="/dev/ttyACM0", baudrate=460800, calibration_path="c.yaml", probe_path="p.yaml")
    assert RigConfig.from_dict(config.to_dict()) == config
    assert RigConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config
    assert config.eye_size() == (1920, 1080) and config.fps == 60.0
    assert RigConfig.from_dict({"mode": "folder"}) == RigConfig(mode="folder")
    assert RigConfig(serial_port="", probe_path="").serial_port is None


@pytest.mark.parametrize("data, words", [
    (["folder"], "not a table"), ({"mode": "usb"}, "Unknown camera mode"), ({"layout": "diagonal"}, "Unknown stereo"),
    ({"colour": "red"}, "unknown settings (colour)"), ({"fps": "fast"}, "frame rate"), ({"fps": -1}, "frame rate"),
    ({"baudrate": 9600.5}, "baud rate"), ({"frame_size": [960]}, "width and a height"),
    ({"frame_size": [960, 0]}, "frame width"), ({"left": 3}, "left must be text"), ({"serial_port": 5}, "serial_port")])
def test_a_bad_stored_config_is_a_value_error_sentence(data, words):
    with pytest.raises(ValueError, match=words.replace("(", r"\(").replace(")", r"\)")) as err:
        RigConfig.from_dict(data)
    assert_sentence(str(err.value))


def test_missing_names_what_each_mode_still_needs():
    calib = {"calibration_path": "c.yaml"}
    assert RigConfig(mode="pair", **calib).missing == "Choose the left camera and the right camera."
    same = RigConfig(mode="pair", left="0", right=" 0 ", **calib)
    assert same.missing.startswith("The left and right cameras are the same")
    assert RigConfig(mode="stacked", **calib).missing == "Choose the camera that delivers both eyes."
    assert RigConfig(mode="video", left="a.avi", **calib).missing == "Choose the right video file."
    assert RigConfig(mode="folder", right="r/*.png", **calib).missing == "Choose the left image pattern."
    uncalibrated = RigConfig(mode="folder", left="l/*.png", right="r/*.png")
    assert uncalibrated.missing.startswith("Choose the stereo calibration") and uncalibrated.source_missing == ""
    assert RigConfig(mode="pair", left="0", right="/dev/video2", **calib).missing == ""


@pytest.mark.slow
def test_hardware_and_demo_rigs_answer_the_rig_protocol_with_their_wizard_feeds(recording, imu_port):
    root, pairs, _ = recording
    hardware = HardwareRig(folder_config(root, serial_port=imu_port.port))
    demo = DemoRig(scale=0.25)
    try:
        for rig in (hardware, demo):
            assert isinstance(rig, Rig) and isinstance(rig.imu, Imu) and rig.description
            make_source, imu = rig.pivot_source()
            assert isinstance(imu, Imu)
            with make_source() as source:
                frame = next(iter(source))
            assert frame.left.shape[1::-1] == rig.calibration.image_size
            if rig is demo:                  # the pivot recording's IMU follows the frame just read
                assert isinstance(imu, SceneImu) and imu.take_samples() == []
                np.testing.assert_allclose(imu.snapshot().earth_from_imu, imu._scene.earth_from_imu(frame.index))
            make_source, imu = rig.tissue_source()          # the turn over tissue: the same contract
            assert isinstance(imu, Imu)
            if rig is demo:
                with make_source() as source:
                    frame = next(iter(source))
                assert frame.left.shape[1::-1] == rig.calibration.image_size
                np.testing.assert_allclose(imu.snapshot().earth_from_imu, imu._scene.earth_from_imu(frame.index))
        assert not hardware.simulated and demo.simulated
        with hardware.board_source() as source:          # the cameras themselves, for the stereo wizard
            np.testing.assert_array_equal(source.read().left, pairs[0][0])
        with demo.board_source() as source:              # a rendered checkerboard seen by the true cameras
            left = source.read().left
        assert left.shape[1::-1] == demo.cameras.image_size and find_corners(left, THESIS_BOARD) is not None
        assert isinstance(AbsentImu(), Imu)
    finally:
        hardware.close()
        demo.close()
