"""Issue 14, readability: every tab fits 1024x700, the acquisition numbers are large and show what was fed, the spread
is coloured against the store limit, status text is never cut unseen, the feeds keep the camera's shape, the pairing
headers are whole, and a node's label does not carry over to the next node."""

import math
import time
from dataclasses import replace

import numpy as np
import pytest
from PySide6.QtCore import QSize

from snreg.demo.rig import DemoRig
from snreg.demo.scene import Schedule
from snreg.imu.monitor import ImuSnapshot
from snreg.registration.report import MissingNode
from snreg.session import IntraopNode
from snreg.session.video import RECENT_DROP_PAIRS, RecorderState, video_text
from snreg.tracking import ProbeFix
from snreg.workflow.acquisition import FrameOutcome, StoreCheck
from snreg_gui.acquisition.health import camera_health
from snreg_gui.acquisition.live_view import PLOT_MIN, arrange
from snreg_gui.acquisition.node_table import NODE_COLUMNS
from snreg_gui.acquisition.screen import AcquisitionScreen
from snreg_gui.acquisition.status import (BAD, NO_VALUE, SPREAD_BAD, SPREAD_GOOD, SPREAD_NONE, StatusLine,
                                          spread_colour)
from snreg_gui.acquisition.worker import FrameResult, StoreRequest
from snreg_gui.app import MainWindow

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)

EULER = (12.34, -4.56, 0.04)          # yaw, pitch, roll fed by the IMU stand-in


class TurnedImu:
    def snapshot(self):
        return ImuSnapshot("streaming", "", 208.0, 0.0, EULER, np.eye(3), 1, 0)


def frame(tip_trocar=(1.26, -2.0, 248.04), spread_mm=0.4, fixes=5, imu_age_s=0.0) -> FrameResult:
    fix = ProbeFix(np.array([0.0, 0.0, 90.0]), np.array([0.0, 0.0, 120.0]), np.array([0.0, 0.0, 1.0]), 1.0,
                   "triangulation", 3)
    tip = None if tip_trocar is None else np.array(tip_trocar)
    outcome = FrameOutcome(0, fix if tip is not None else None, "" if tip is not None else "probe not seen", tip,
                           fixes, spread_mm, spread_mm < 1.0, False, 5.0, store_check=StoreCheck(""))
    rgb = np.zeros((54, 96, 3), np.uint8)
    imu = replace(TurnedImu().snapshot(), age_s=imu_age_s)
    return FrameResult(outcome, rgb, rgb, None, None, imu, 0.0, 30.0, time.perf_counter_ns())


@pytest.fixture
def screen(qtbot):
    screen = AcquisitionScreen(TurnedImu(), fixes_per_node=5, max_spread_mm=2.0)
    qtbot.addWidget(screen)
    screen.resize(1000, 640)
    screen.show()
    return screen


def test_tip_and_angles_show_the_numbers_fed(qtbot, screen):
    screen.show_result(frame())
    qtbot.waitUntil(lambda: screen.tip_values.texts() == ["1.3", "-2.0", "248.0"], timeout=2_000)
    assert screen.angles.texts() == ["12.3", "-4.6", "0.0"]
    assert screen.tip_values.values[0].font().pointSizeF() > 1.5 * screen.store_reason.font().pointSizeF()
    screen.show_result(frame(tip_trocar=None))
    qtbot.waitUntil(lambda: screen.tip_values.texts() == [NO_VALUE] * 3, timeout=2_000)
    assert screen.tip_trocar.text() == "no fix (probe not seen)"


def test_the_angles_of_an_imu_gone_silent_are_greyed_until_it_speaks_again(qtbot, screen):
    colours = [value.styleSheet() for value in screen.angles.values]
    assert all(colours) and SPREAD_NONE not in "".join(colours)
    screen.show_result(frame(imu_age_s=3.2))                      # no sample for 3.2 s: the last angles, greyed
    qtbot.waitUntil(lambda: screen.angles.stale, timeout=2_000)
    assert screen.angles.texts() == ["12.3", "-4.6", "0.0"]
    assert all(SPREAD_NONE in value.styleSheet() for value in screen.angles.values)
    assert np.isnan(screen.orientation.values[-1]).all()             # the plot: a gap, not the last angles again
    screen.show_result(frame(imu_age_s=0.01))
    qtbot.waitUntil(lambda: not screen.angles.stale, timeout=2_000)
    assert screen.orientation.values[-1] == pytest.approx([12.3, -4.6, 0.0], abs=0.05)
    assert [value.styleSheet() for value in screen.angles.values] == colours


def test_the_spread_is_green_within_the_store_limit_and_red_beyond(qtbot, screen):
    assert (spread_colour(1.99, 2.0), spread_colour(2.01, 2.0), spread_colour(math.nan, 2.0)) == (
        SPREAD_GOOD, SPREAD_BAD, SPREAD_NONE)
    screen.show_result(frame(spread_mm=1.5))
    qtbot.waitUntil(lambda: screen.spread_value.text() == "1.50", timeout=2_000)
    assert SPREAD_GOOD in screen.spread_value.styleSheet()
    screen.show_result(frame(spread_mm=2.5))
    qtbot.waitUntil(lambda: screen.spread_value.text() == "2.50", timeout=2_000)
    assert SPREAD_BAD in screen.spread_value.styleSheet()
    screen.spread_spin.setValue(3.0)                  # the limit the worker refuses by: 2.5 mm is within it now
    assert SPREAD_GOOD in screen.spread_value.styleSheet()
    screen.show_result(frame(spread_mm=math.nan))     # the window is not full yet
    qtbot.waitUntil(lambda: screen.spread_value.text() == NO_VALUE, timeout=2_000)
    assert SPREAD_NONE in screen.spread_value.styleSheet()


def stored(node_id: str, label: str, counts: float = math.nan) -> IntraopNode:
    """A stored node whose covariance's longest axis has an sd of 4 mm: a 90 % radius of 4 x 2.50 = 10.0 mm."""
    return IntraopNode(node_id, label, 0, np.array([1.0, 2.0, 250.0]), np.array([1.0, 2.0, 2.0]), 0.3, 60, counts,
                       cov_trocar_mm2=np.diag([1.0, 4.0, 16.0]))


def test_the_camera_line_is_red_while_the_encoder_drops_pairs_and_not_for_drops_long_past():
    now = RecorderState(started=True, written=300, dropped=4, written_at_drop=300)
    past = RecorderState(started=True, written=300 + RECENT_DROP_PAIRS, dropped=4, written_at_drop=300)
    styles = [camera_health(replace(frame(), outcome=replace(frame().outcome, video=video_text(state))), 0.0)[1]
              for state in (now, past)]
    assert styles == [BAD, ""]


def test_the_label_typed_for_a_node_does_not_carry_over_to_the_next(qtbot, screen):
    screen.label_edit.setText("OBT R")
    screen.counts_edit.setText("1520")
    screen.show_result(frame())
    with qtbot.waitSignal(screen.store_requested) as asked:
        screen.request_store()
    assert asked.args == [StoreRequest("OBT R", 1520.0, "button")]
    screen.add_node(stored("SN3", "OBT R", 1520.0))
    assert screen.label_edit.text() == "" and screen.counts_edit.text() == ""
    assert "SN3 was 'OBT R'" in screen.label_edit.placeholderText()
    row = [screen.nodes.item(0, column).text() for column in range(len(NODE_COLUMNS))]
    assert row == ["SN3", "OBT R", "1.0", "2.0", "250.0", "\u00b110.0", "0.30", "1520"]
    screen.label_edit.setText("EXT L")                # typed for the next node while SN4 (auto-stored) was stored
    screen.add_node(stored("SN4", ""))
    assert screen.label_edit.text() == "EXT L"


def test_a_status_line_takes_the_lines_its_text_needs_and_is_never_cut(qtbot):
    line = StatusLine("IMU: streaming", 1, min_width=100)
    qtbot.addWidget(line)
    line.resize(160, line.height())
    one_line = line.height()
    text = "IMU: stale, 0 Hz, 3 corrupt  STALE (no sample for 4.2 s: check the USB cable of the IMU and its port)"
    line.setText(text)
    assert line.shown_lines == line.needed_lines() > 3 and line.height() > 3 * one_line
    assert line.text() == text and line.toolTip() == text
    line.setText("IMU: streaming")
    assert line.shown_lines == 1 and line.height() == one_line


@pytest.mark.parametrize("size", [(1024 - 40, 700 - 120), (1920 - 500, 1080 - 130)])
def test_the_feeds_keep_the_camera_shape_and_the_plot_keeps_its_room(size):
    width, height = size
    layout = arrange(width, height, 9 / 16)
    for x, y, w, h in (layout.left, layout.right):
        assert abs(h - w * 9 / 16) <= 1                            # no black bands around the image
        assert 0 <= x and x + w <= width and 0 <= y and y + h <= height
    x, y, w, h = layout.plot
    assert w >= PLOT_MIN.width() and h >= PLOT_MIN.height() and x + w <= width and y + h <= height
    feeds_area = 2 * layout.left[2] * layout.left[3]
    assert feeds_area > 0.45 * width * height                      # the feeds get most of the pane


@pytest.fixture
def demo_window(qtbot, tmp_path):
    window = MainWindow(str(tmp_path / "demo.h5"), demo=True, rig=DemoRig(schedule=Schedule(rest_frames=90)))
    qtbot.addWidget(window)
    yield window
    window.shutdown()


@pytest.mark.slow
def test_every_tab_fits_1024x700_and_the_pairing_headers_are_whole(qtbot, demo_window):
    window = demo_window
    missing = [MissingNode(k, f"P{k + 1}", "INT R", np.array([1.0, 2.0, 3.0]), 12.0) for k in range(3)]
    window.acquisition.show_missing(missing)
    window.acquisition.show_link_state("1 client on 127.0.0.1:18944")
    window.resize(1024, 700)
    with qtbot.waitExposed(window):
        window.show()
    for index in range(window.tabs.count()):
        window.tabs.setCurrentIndex(index)
        hint = window.minimumSizeHint()
        assert hint.width() <= 900 and hint.height() <= 700, window.tabs.tabText(index)
    assert window.size() == QSize(1024, 700)                         # nothing shown made the window grow
    window.tabs.setCurrentIndex(0)
    side = window.acquisition.splitter.widget(1)
    qtbot.waitUntil(lambda: side.isVisible() and side.viewport().height() > 0, timeout=2_000)
    assert not side.verticalScrollBar().isVisible()                  # the whole side column shows at 700 px
    assert window.acquisition.nodes.height() >= window.acquisition.nodes.minimumHeight()
    panel = window.registration
    window.tabs.setCurrentWidget(panel)
    qtbot.waitUntil(lambda: panel.pairing_table.width() > 0 and panel.pairing_table.isVisible(), timeout=2_000)
    header, metrics = panel.pairing_table.horizontalHeader(), panel.pairing_table.fontMetrics()
    for column in range(panel.pairing_table.columnCount()):
        caption = panel.pairing_table.horizontalHeaderItem(column).text()
        widest = max(metrics.horizontalAdvance(line) for line in caption.split("\n"))
        assert header.sectionSize(column) >= widest, caption
    assert sum(header.sectionSize(c) for c in range(header.count())) <= panel.pairing_table.viewport().width()
