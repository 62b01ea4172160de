"""The acquisition screen lists the SPECT nodes not found yet and draws them on both feeds where the camera sees
them: a region at the expected pixel, an arrow at the border for one off screen, words for an unconfident pairing."""

import time

import numpy as np
import pytest
from PySide6.QtGui import QColor

from snreg import geometry
from snreg.camera import thesis_calibration
from snreg.imu.monitor import ImuSnapshot
from snreg.registration.report import MissingNode
from snreg.tracking.stereo import StereoTracker
from snreg.workflow.acquisition import FrameOutcome
from snreg.workflow.display import DISPLAY_SCALE
from snreg.workflow.navigation import NOT_CONFIDENT, UPDATING, NavigationState, navigate
from snreg_gui.acquisition.hot_spots import feed_layer, guidance_text
from snreg_gui.acquisition.screen import AcquisitionScreen
from snreg_gui.acquisition.worker import FrameResult

CALIBRATION = thesis_calibration().scaled(0.2)           # 384 x 216 camera pixels, shown at half that
TARGET, GREY, BANNER = QColor(80, 200, 255), QColor(150, 150, 150), QColor(255, 170, 60)


class LevelImu:
    def snapshot(self):
        return ImuSnapshot("streaming", "", 208.0, 0.0, (0.0, 0.0, 0.0), np.eye(3), 1, 0)


def frame(state: NavigationState, tip_camera, pose=np.eye(4)) -> tuple[FrameResult, list]:
    """A frame whose tip is at ``tip_camera`` (camera = trocar frame here), with the worker's layers and words."""
    width, height = CALIBRATION.image_size
    rgb = np.zeros((round(height * DISPLAY_SCALE), round(width * DISPLAY_SCALE), 3), np.uint8)
    tip = geometry.apply(geometry.invert(pose), np.asarray(tip_camera, float)[None])[0]
    outcome = FrameOutcome(0, None, "moving", tip, 0, float("nan"), False, False, 5.0)
    views = navigate(list(state.targets), pose, StereoTracker(CALIBRATION).project, CALIBRATION.image_size, tip)
    layers = [feed_layer(views, eye, state, DISPLAY_SCALE) for eye in (0, 1)]
    return FrameResult(outcome, rgb, rgb, None, None, LevelImu().snapshot(), 0.0, 30.0, time.perf_counter_ns(),
                       *layers, guidance_text(views, state)), views


def painted(feed, colour: QColor, centre, half: float) -> int:
    """Pixels of ``colour`` (within 12 per channel) painted within ``half`` display px of the frame pixel ``centre``."""
    image = feed.grab().toImage()
    target = feed._target()
    scale = target.width() / feed.image_size[0]
    at = feed._at(target, scale, *centre)
    count = 0
    for x in range(int(at.x() - half * scale), int(at.x() + half * scale) + 1):
        for y in range(int(at.y() - half * scale), int(at.y() + half * scale) + 1):
            if 0 <= x < image.width() and 0 <= y < image.height():
                c = image.pixelColor(x, y)
                count += max(abs(c.red() - colour.red()), abs(c.green() - colour.green()),
                             abs(c.blue() - colour.blue())) <= 12
    return count


def test_missing_hot_spots_are_drawn_where_the_camera_sees_them_with_an_arrow_for_one_off_screen(qtbot):
    screen = AcquisitionScreen(LevelImu(), fixes_per_node=5)
    qtbot.addWidget(screen)
    screen.resize(1366, 768)
    screen.show()
    near = MissingNode(2, "P3", "INT R", np.array([10.0, -5.0, 120.0]), 6.0)
    off = MissingNode(4, "P5", "OBT L", np.array([200.0, 0.0, 100.0]), 8.0)        # far right of the view
    state = NavigationState((near, off), ("P1", "P2"), confident=True)
    screen.show_missing(list(state.targets))
    assert "P3 INT R" in screen.missing_list.text() and "P5 OBT L" in screen.missing_list.text()
    result, views = frame(state, [10.0, -5.0, 100.0])                              # the tip 20 mm in front of P3
    screen.show_result(result)
    qtbot.waitUntil(lambda: screen.left_feed.hot_spots is not None, timeout=5_000)
    K = CALIBRATION.K1
    expected = DISPLAY_SCALE * np.array([K[0, 0] * 10.0 / 120.0 + K[0, 2], K[1, 1] * -5.0 / 120.0 + K[1, 2]])
    drawn, arrow = screen.left_feed.hot_spots.marks
    np.testing.assert_allclose(drawn.centre, expected, atol=0.05)
    assert drawn.text == "P3 20 mm deeper" and drawn.axes[1] > 0
    assert arrow.centre is None and np.allclose(arrow.arrow_way, [1.0, 0.0], atol=0.03)   # from the image centre
    assert screen.left_feed.hot_spots.note == "found: P1, P2"
    assert screen.guidance.text() == "P3: 20 mm, 20 mm deeper"
    qtbot.waitUntil(lambda: painted(screen.left_feed, TARGET, drawn.centre, drawn.axes[0] + 3) > 10, timeout=5_000)
    assert painted(screen.left_feed, TARGET, arrow.arrow_at, 6) > 10           # the arrow, at the right border
    assert screen.right_feed.hot_spots.marks[0].centre[0] < drawn.centre[0]   # the right eye sees it further left


def test_an_unconfident_pairing_is_said_on_the_feed_and_nothing_is_drawn_as_confident(qtbot):
    screen = AcquisitionScreen(LevelImu(), fixes_per_node=5)
    qtbot.addWidget(screen)
    screen.resize(1366, 768)
    screen.show()
    near = MissingNode(2, "P3", "INT R", np.array([10.0, -5.0, 120.0]), 6.0)
    state = NavigationState((near,), ("P1", "P2", "P4"), confident=False)
    screen.show_missing([near])
    result, _ = frame(state, [0.0, 0.0, 100.0])
    screen.show_result(result)
    qtbot.waitUntil(lambda: screen.left_feed.hot_spots is not None, timeout=5_000)
    layer = screen.left_feed.hot_spots
    assert layer.banner == NOT_CONFIDENT and not layer.confident
    assert screen.guidance.text() == NOT_CONFIDENT                          # no way given as if confident
    mark = layer.marks[0]
    qtbot.waitUntil(lambda: painted(screen.left_feed, GREY, mark.centre, mark.axes[0] + 3) > 10, timeout=5_000)
    assert painted(screen.left_feed, TARGET, mark.centre, mark.axes[0] + 3) == 0
    updating, _ = frame(NavigationState((near,), ("P1",), confident=True).updating(), [0.0, 0.0, 100.0])
    screen.show_result(updating)                                             # a registration running: greyed too
    qtbot.waitUntil(lambda: screen.left_feed.hot_spots.banner == UPDATING, timeout=5_000)
    assert not screen.left_feed.hot_spots.confident and screen.guidance.text() == UPDATING
    screen.show_missing([])                                                  # every node paired: nothing listed
    assert screen.missing_list.text() == "" and screen.guidance.text() == ""


def test_the_worker_draws_from_the_cameras_pose_at_the_frames_orientation_and_insertion(qtbot):
    from types import SimpleNamespace

    from snreg.chain import trocar_from_camera as pose_of
    from snreg.demo.surgery_scene import surgery_demo_chain
    from snreg.workflow.acquisition import ImuReading
    from snreg_gui.acquisition.worker import AcquisitionWorker

    chain = surgery_demo_chain()
    slid = chain.with_insertion(float(np.linalg.norm(chain.imu_from_camera[:3, 3])) - chain.imu_trocar_mm + 10.0)
    orientation = geometry.rotation_from_euler(20.0, -10.0, 5.0)
    trocar_from_camera = pose_of(slid, orientation)                   # the pose at the slid chain
    ahead = geometry.apply(trocar_from_camera, np.array([[0.0, 0.0, 120.0]]))[0]     # on the optical axis
    worker = AcquisitionWorker(None, CALIBRATION, None, chain, None, None, 30.0)
    worker.acquisition = SimpleNamespace(chain=chain, tracker=StereoTracker(CALIBRATION))
    worker.set_navigation(NavigationState((MissingNode(0, "P1", "", ahead, 5.0),), (), confident=True))
    outcome = FrameOutcome(0, None, "", None, 0, float("nan"), False, False, 5.0,
                           insertion=SimpleNamespace(chain=slid))
    left, right, words = worker._hot_spots(outcome, ImuReading(orientation))
    K = CALIBRATION.K1
    np.testing.assert_allclose(left.marks[0].centre, DISPLAY_SCALE * K[:2, 2], atol=0.05)
    assert right.marks[0].centre[0] < left.marks[0].centre[0] and words == "P1: no probe fix"
    unslid = FrameOutcome(0, None, "", None, 0, float("nan"), False, False, 5.0)     # the chain's own insertion
    moved, _, _ = worker._hot_spots(unslid, ImuReading(orientation))
    np.testing.assert_allclose(moved.marks[0].centre, left.marks[0].centre, atol=0.05)   # still on the axis...
    assert moved.marks[0].axes[0] == pytest.approx(left.marks[0].axes[0] * 120.0 / 130.0, rel=0.01)   # 10 mm deeper


def test_a_hot_spot_whose_region_is_unknown_says_so_instead_of_a_precise_point():
    known = MissingNode(2, "P3", "INT R", np.array([10.0, -5.0, 120.0]), 6.0)
    unknown = MissingNode(3, "P4", "INT L", np.array([-10.0, 5.0, 120.0]), float("nan"))
    state = NavigationState((known, unknown), (), confident=True)
    views = navigate(list(state.targets), np.eye(4), StereoTracker(CALIBRATION).project, CALIBRATION.image_size)
    texts = [mark.text for mark in feed_layer(views, 0, state, DISPLAY_SCALE).marks]
    assert texts == ["P3", "P4 (region unknown)"]
