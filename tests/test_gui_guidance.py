"""The acquisition screen lists the SPECT nodes not found yet and points from the live tip to the nearest one."""

import time

import numpy as np

from snreg.imu.monitor import ImuSnapshot
from snreg.registration.report import MissingNode
from snreg.workflow.acquisition import FrameOutcome
from snreg_gui.acquisition.screen import AcquisitionScreen
from snreg_gui.acquisition.worker import FrameResult


class LevelImu:
    def snapshot(self):
        return ImuSnapshot("streaming", "", 208.0, 0.0, (0.0, 0.0, 0.0), np.eye(3), 1, 0)


def frame_with_tip(tip) -> FrameResult:
    rgb = np.zeros((54, 96, 3), np.uint8)
    outcome = FrameOutcome(0, None, "moving", np.asarray(tip, float), 0, float("nan"), False, False, 5.0)
    return FrameResult(outcome, rgb, rgb, None, None, LevelImu().snapshot(), 0.0, 30.0, time.perf_counter_ns())


def test_missing_nodes_and_the_live_pointer_to_the_nearest(qtbot):
    screen = AcquisitionScreen(LevelImu(), fixes_per_node=5)
    qtbot.addWidget(screen)
    missing = [MissingNode(2, "P3", "INT R", np.array([10.0, 0.0, 200.0]), 12.0),
               MissingNode(4, "P5", "OBT L", np.array([-60.0, 5.0, 210.0]), 15.0)]
    screen.show_missing(missing)
    assert "P3 INT R" in screen.missing_list.text() and "P5 OBT L" in screen.missing_list.text()
    screen.show_result(frame_with_tip([10.0, 0.0, 240.0]))            # 40 mm beyond P3 along +z
    qtbot.waitUntil(lambda: screen.guidance.text().startswith("nearest missing P3: 40 mm -z"), timeout=2_000)
    screen.show_result(frame_with_tip([-55.0, 5.0, 212.0]))
    qtbot.waitUntil(lambda: "P5" in screen.guidance.text() and "inside its bound" in screen.guidance.text(),
                    timeout=2_000)
    screen.show_missing([])                                               # every node paired: nothing shown
    assert screen.missing_list.text() == "" and screen.guidance.text() == ""


def test_the_nearest_missing_node_is_circled_on_both_feeds(qtbot):
    screen = AcquisitionScreen(LevelImu(), fixes_per_node=5)
    qtbot.addWidget(screen)
    screen.show_missing([MissingNode(2, "P3", "INT R", np.array([10.0, 0.0, 200.0]), 12.0)])
    rgb = np.zeros((54, 96, 3), np.uint8)
    outcome = FrameOutcome(0, None, "moving", np.array([0.0, 0.0, 180.0]), 0, float("nan"), False, False, 5.0)
    screen.show_result(FrameResult(outcome, rgb, rgb, None, None, LevelImu().snapshot(), 0.0, 30.0,
                                   time.perf_counter_ns(), (np.array([40.0, 20.0]), 8.0, "P3"),
                                   (np.array([30.0, 20.0]), 8.0, "P3")))
    qtbot.waitUntil(lambda: screen.left_feed._circle is not None, timeout=2_000)
    (centre, radius, text) = screen.left_feed._circle
    assert tuple(centre) == (40.0, 20.0) and radius == 8.0 and text == "P3"
    assert tuple(screen.right_feed._circle[0]) == (30.0, 20.0)
    screen.show_result(frame_with_tip([0.0, 0.0, 180.0]))                  # no circle from the worker: none drawn
    qtbot.waitUntil(lambda: screen.left_feed._circle is None, timeout=2_000)
