"""The review screen shows the recorded video: the pair at the cursor with the overlay as tracked then, and a node's
store window when it is selected."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pytestqt")

from snreg.session import Session  # noqa: E402
from snreg_gui.review.screen import ReviewScreen  # noqa: E402

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)


def test_scrubbing_shows_the_recorded_pair_with_its_overlay_and_a_node_jumps_to_its_window(qtbot, recorded_video):
    path, _, _ = recorded_video
    screen = ReviewScreen()
    qtbot.addWidget(screen)
    with qtbot.waitSignal(screen.loaded, timeout=60_000):
        screen.load(str(path))
    qtbot.waitUntil(lambda: screen.scrubber.video is not None, timeout=20_000)
    video = screen.scrubber.video
    with Session.open(path) as session:
        nodes = session.intraop_records()
    t_mid = float(video.times_s[len(video.times_s) // 2])
    with qtbot.waitSignal(screen.scrubber.frame_ready, timeout=20_000) as shown:
        screen.timelines._dragged(t_mid)                     # as a drag of the cursor ends there
    frame = shown.args[0]
    assert frame.row == len(video.times_s) // 2 and frame.left_rgb.shape == (270, 480, 3)
    assert screen.snapshots.left_view._image is not None and screen.snapshots.left_view.title.startswith("left: frame")
    assert all(cursor.value() == pytest.approx(t_mid) for cursor in screen.timelines.cursors)
    with qtbot.waitSignal(screen.scrubber.frame_ready, timeout=20_000) as shown:
        screen.node_table.selectRow(1)
    frame = shown.args[0]
    node_t = (nodes[1].time_ns - screen._review.t0_ns) / 1e9
    assert frame.t_s == pytest.approx(node_t, abs=1e-6) and frame.overlay_left is not None
    tip = np.asarray(frame.overlay_left[0])
    assert 0 <= tip[0] < 480 and 0 <= tip[1] < 270               # the tip drawn inside the frame
    start, end = screen.timelines.windows[0].getRegion()
    assert screen.timelines.windows[0].isVisible() and end == pytest.approx(node_t) and start < end
    screen.shutdown()
