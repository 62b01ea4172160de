"""What keeps the live acquisition screen cheap on the GUI thread (issue 36), and still right: the IMU plot's y range
moves rarely and in whole steps, yet always holds the angles; Store SN's state and reason are set again only when
they change; a status line counts its lines without laying out what fits on one, as a full layout would, and a new
text of as many lines is a repaint, not a relayout."""

import numpy as np
import pytest
from PySide6.QtCore import QEvent, QObject, QRect, Qt
from PySide6.QtWidgets import QApplication
from test_gui_acquisition import StillImu, frame_without_fix

from snreg_gui.acquisition.orientation_plot import (ANGLE_COLOURS, MIN_SPAN_DEG, RANGE_STEP_DEG, REDRAW_HZ,
                                                     OrientationPlot, y_range)
from snreg_gui.acquisition.screen import AcquisitionScreen
from snreg_gui.acquisition.status import BigNumber, StatusLine
from snreg_gui.common.feed_view import FeedView


class Changes(QObject):
    """Counts the tooltip and enabled-state changes its watched widgets are told of."""

    WATCHED = (QEvent.Type.ToolTipChange, QEvent.Type.EnabledChange)

    def __init__(self, *widgets):
        super().__init__()
        self.count = 0
        for widget in widgets:
            widget.installEventFilter(self)

    def eventFilter(self, watched, event):              # noqa: N802 (Qt's name)
        self.count += event.type() in self.WATCHED
        return False


def test_the_y_range_holds_the_angles_in_whole_steps_and_stays_while_they_stay_inside():
    rng = np.random.default_rng(4)
    held = 12.3 + rng.normal(0.0, 0.05, (300, 3))                # a still endoscope: sensor noise only
    shown = y_range(held, None)
    assert shown[0] <= held.min() and held.max() <= shown[1]
    assert shown[1] - shown[0] >= MIN_SPAN_DEG and all(end % RANGE_STEP_DEG == 0 for end in shown)
    for _ in range(50):                                           # more noise within it: the range stays
        assert y_range(12.3 + rng.normal(0.0, 0.05, (300, 3)), shown) is shown
    turned = np.vstack([held[100:], 30.0 + rng.normal(0.0, 0.05, (100, 3))])     # a turn to 30 degrees
    wider = y_range(turned, shown)
    assert wider[0] <= turned.min() and turned.max() <= wider[1] and wider != shown
    settled = y_range(30.0 + rng.normal(0.0, 0.05, (300, 3)), wider)             # the turn scrolled out of view
    assert settled[1] - settled[0] < (wider[1] - wider[0]) / 2 and settled[0] <= 29.5 and 30.5 <= settled[1]
    assert y_range(np.full((300, 3), np.nan), None) is None and y_range(np.full(3, np.nan), shown) is shown


def test_the_plot_sets_its_range_only_when_the_angles_leave_it(qtbot):
    plot = OrientationPlot()
    qtbot.addWidget(plot)
    rng = np.random.default_rng(5)
    for frame in range(120):
        plot.append((40.0, -3.0, 2.0) + rng.normal(0.0, 0.05, 3))
        if frame % 6 == 5:
            plot.redraw()
    assert plot.range_changes == 1
    low, high = plot.getViewBox().viewRange()[1]
    assert (low, high) == pytest.approx(plot.shown_range) and low <= -3.2 and 40.2 <= high
    plot.append((55.0, -3.0, 2.0))                                # a turn beyond the range
    plot.redraw()
    assert plot.range_changes == 2 and plot.getViewBox().viewRange()[1][1] >= 55.0
    yaw = plot.listDataItems()[0].getData()
    assert yaw[0][-1] == 0 and yaw[1][-1] == 55.0 and yaw[1][-2] == pytest.approx(40.0, abs=0.3)
    assert np.isnan(yaw[1][0]) and np.isfinite(yaw[1][-121:]).all() and np.isnan(yaw[1][:-121]).all()
    for k in range(400):                                          # once the ring is full, the oldest go
        plot.append((float(k), 0.0, 0.0))
    np.testing.assert_array_equal(plot.values[:, 0], np.arange(100.0, 400.0))


def test_the_imu_plot_redraws_at_most_at_its_rate_and_ends_on_the_newest_sample(qtbot):
    """Issue 36: the curves are set at most ``REDRAW_HZ`` times a second however fast the pairs come, and the newest
    sample is drawn once an interval has passed, also when no more come."""
    plot = OrientationPlot()
    qtbot.addWidget(plot)
    frames, fps = 150, 60.0                                        # 2.5 s of pairs at 60 Hz, a tick after each
    for k in range(frames):
        plot.append((float(k), -3.0, 2.0))
        plot.redraw_due(k / fps)
    assert 2 <= plot.redraws <= (frames / fps) * REDRAW_HZ + 1
    yaw = plot.listDataItems()[0].getData()[1]
    assert yaw[-1] < frames - 1                                    # the last samples wait for the next interval
    shown_at = (frames - 1) / fps + 1.0 / REDRAW_HZ
    assert plot.redraw_due(shown_at)                               # the frames stopped: shown within an interval
    assert plot.listDataItems()[0].getData()[1][-1] == frames - 1
    drawn = plot.redraws
    assert not plot.redraw_due(shown_at + 10.0) and plot.redraws == drawn     # nothing new: nothing redrawn
    later = shown_at + 10.0
    plot.append((500.0, -3.0, 2.0))
    assert plot.redraw_due(later)                                  # long after the last redraw: at once
    plot.append((501.0, -3.0, 2.0))
    assert not plot.redraw_due(later + 0.5 / REDRAW_HZ)            # half an interval after it: it waits
    assert plot.redraw_due(later + 1.0 / REDRAW_HZ) and plot.listDataItems()[0].getData()[1][-1] == 501.0


def test_the_imu_plot_legend_lies_outside_the_plot_area_and_names_each_curve(qtbot):
    """The legend covered the yaw line when yaw sat near the top of the range; it is now above the plot area."""
    plot = OrientationPlot()
    qtbot.addWidget(plot)
    plot.resize(340, 300)
    plot.show()
    qtbot.waitExposed(plot)
    for _ in range(10):
        plot.append((0.0, 3.0, -100.0))                            # yaw at the top of the range, as in the demo
    plot.redraw()
    title, area = plot.plotItem.titleLabel, plot.plotItem.vb.sceneBoundingRect()
    assert title.isVisible() and not title.sceneBoundingRect().intersects(area)
    assert title.sceneBoundingRect().bottom() <= area.top() and title.sceneBoundingRect().height() > 5
    text = title.item.toPlainText()
    assert all(name in text for name in ANGLE_COLOURS) and plot.plotItem.legend is None
    assert all(colour in title.text for colour in ANGLE_COLOURS.values())


def test_store_sn_is_set_again_only_when_its_state_changes_and_is_right_after_a_change(qtbot):
    screen = AcquisitionScreen(StillImu(), fixes_per_node=5)
    qtbot.addWidget(screen)
    screen.show_result(frame_without_fix("no probe stripe found in the left image"))
    said = "not ready: collecting fixes, 0 of 5 (no valid fix: no probe stripe found in the left image)"
    assert screen.store_reason.text() == said == screen.store_reason.toolTip() == screen.store_button.toolTip()
    changes = Changes(screen.store_reason, screen.store_button, screen.landmark_picker.button)
    for _ in range(20):                                           # pair after pair saying the same
        screen.show_result(frame_without_fix("no probe stripe found in the left image"))
    assert changes.count == 0
    screen.show_result(frame_without_fix("the probe is out of view"))
    said = "not ready: collecting fixes, 0 of 5 (no valid fix: the probe is out of view)"
    assert screen.store_reason.text() == said == screen.store_reason.toolTip() == screen.store_button.toolTip()
    assert changes.count > 0 and screen.store_button.isEnabled()
    screen.set_paused(True)                                       # a change of state, not only of words
    assert not screen.store_button.isEnabled() and not screen.landmark_picker.button.isEnabled()
    assert screen.store_reason.text() == "paused for calibration"


def _wrapped(line, text: str, width: int) -> int:
    """The lines ``text`` takes in ``line``'s font, word-wrapped at ``width`` px, laid out in full."""
    metrics = line.fontMetrics()
    return -(-metrics.boundingRect(QRect(0, 0, width, 10_000), Qt.TextFlag.TextWordWrap, text).height()
             // metrics.lineSpacing())


def test_a_status_line_counts_its_lines_as_a_full_layout_would_at_each_width_and_font(qtbot):
    reserve = "camera 999.9 mm, +99.9 mm since calibration, tracked\\nthe camera is off the pivot model: check both"
    line = StatusLine("camera 171.0 mm", 1, min_width=100, reserve=reserve)
    qtbot.addWidget(line)
    for width in (600, 220, 120):
        line.resize(width, line.height())
        inner = line.contentsRect().width()
        for text in ("camera 171.0 mm", "two\\nlines", "a status that says a good deal more than fits on one line "
                     "of a narrow side column, so that it wraps"):
            line.setText(text)
            assert line.needed_lines() == max(1, _wrapped(line, text, inner), _wrapped(line, reserve, inner))
    font = line.font()
    font.setPointSizeF(font.pointSizeF() * 2)
    line.setFont(font)                                            # the reserve takes more lines in a larger font
    inner = line.contentsRect().width()
    assert line.needed_lines() == max(_wrapped(line, line.text(), inner), _wrapped(line, reserve, inner))


class LayoutRequests(QObject):
    """Counts the layout requests the application delivers anywhere."""

    def __init__(self):
        super().__init__()
        self.count = 0
        QApplication.instance().installEventFilter(self)

    def eventFilter(self, watched, event):              # noqa: N802 (Qt's name)
        self.count += event.type() == QEvent.Type.LayoutRequest
        return False

    def settle(self, rounds: int = 50) -> None:
        """Process events until a round delivers no layout request (the window's first layout done), then count
        from 0."""
        for _ in range(rounds):
            before = self.count
            QApplication.processEvents()
            if self.count == before:
                break
        self.count = 0


def test_a_new_status_text_is_painted_without_laying_the_column_out_again(qtbot):
    screen = AcquisitionScreen(StillImu(), fixes_per_node=5)
    qtbot.addWidget(screen)
    screen.resize(1280, 760)
    screen.show()
    qtbot.waitExposed(screen)
    line = screen.tip_trocar
    line.setText("no fix yet, first")
    requests = LayoutRequests()
    requests.settle()
    painted = []
    line.paintEvent = lambda event: painted.append(line.text()) or StatusLine.paintEvent(line, event)
    for k in range(10):                                           # one line of text each, changing every time
        line.setText(f"no fix (no probe stripe found, pair {k})")
        line.repaint()
    QApplication.processEvents()
    assert requests.count == 0
    assert painted[-1] == line.text() == line.toolTip() == "no fix (no probe stripe found, pair 9)"
    line.setText("a status that says a good deal more than fits on one line of the side column, so that it wraps "
                 "over more lines than the line reserves, as a long refusal does")
    assert line.shown_lines == line.needed_lines() > 1
    QApplication.processEvents()
    assert requests.count > 0                                     # a taller line: then the column is laid out again


def test_a_big_number_shown_again_unchanged_is_still_right_after_each_change(qtbot):
    number = BigNumber("-888.8")
    qtbot.addWidget(number)
    shown = []
    for value in (12.34, 12.31, 12.31, 12.46, float("nan"), None, -0.01, 3.0, 3.0):
        number.show_value(value)
        shown.append(number.text())
    assert shown == ["12.3", "12.3", "12.3", "12.5", "\u2014", "\u2014", "0.0", "3.0", "3.0"]
    number.show_value(7.25, 2)
    assert number.text() == "7.25"


def test_the_probes_boxes_a_hot_spots_words_keep_clear_of_are_where_its_marker_and_axis_are_drawn(qtbot):
    feed = FeedView("left")
    qtbot.addWidget(feed)
    feed.resize(292, 164)
    feed.show_frame(np.full((108, 192, 3), 140, np.uint8), np.array([[100.0, 60.0], [150.0, 40.0]]), 114.8)
    target = feed._target()
    scale = target.width() / 192
    tip, up = (feed._at(target, scale, x, y) for x, y in ([100.0, 60.0], [150.0, 40.0]))   # as painted
    centres = [(tip.x() + (up.x() - tip.x()) * k / 8, tip.y() + (up.y() - tip.y()) * k / 8) for k in range(9)]
    radii = [7.0] + [3.0] * 8
    drawn = feed._drawn_boxes(target, scale)
    assert len(drawn) == 1 + 9 + 1                                # the title, the tip and 8 axis points, the depth
    np.testing.assert_allclose(drawn[1:10], [[x - r, y - r, x + r, y + r] for (x, y), r in zip(centres, radii)])
    at, text = feed._depth_label(tip, target)
    assert drawn[10][0] == pytest.approx(at.x()) and text == "114.8 mm"
