"""What keeps the live acquisition screen cheap on the GUI thread (issue 36), and still right: the IMU plot's y range
moves rarely and in whole steps, yet always holds the angles."""

import numpy as np
import pytest

from snreg_gui.acquisition.orientation_plot import MIN_SPAN_DEG, RANGE_STEP_DEG, OrientationPlot, y_range


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
