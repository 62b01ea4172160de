"""The words a camera feed writes about the hot spots not found yet (snreg_gui.common.feed_view): each readable, none
over another or over the probe's marker and depth label, none cut by the image's edge, at the size a feed has in a
1024x700 window (issue 36: "P4 8 mm nearer" was written under the probe's "114.8 mm" when the probe rested beside
the hot spot, and a stale banner ran past both edges of the small feed)."""

import numpy as np
import pytest

from snreg.workflow.navigation import NOT_CONFIDENT, UPDATING
from snreg_gui.common.feed_view import FeedView, HotSpotLayer, HotSpotMark
from snreg_gui.registration.navigation import OUT_OF_DATE       # the longest banner


def _overlap(a, b) -> float:
    return max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))


def _feed(qtbot, tip, up):
    feed = FeedView("left")
    qtbot.addWidget(feed)
    feed.resize(292, 164)                                # a feed's size in the 1024x700 window
    feed.show()
    frame = np.full((108, 192, 3), 140, np.uint8)        # the surgery demo's quarter-resolution frame, halved
    feed.show_frame(frame, np.array([tip, up], dtype=float), 114.8)
    return feed


def _inside(box, target) -> bool:
    return (target.left() <= box[0] and box[2] <= target.right() + 1 and target.top() <= box[1]
            and box[3] <= target.bottom() + 1)


@pytest.mark.parametrize("banner", ["", NOT_CONFIDENT, UPDATING, OUT_OF_DATE])
def test_hot_spot_words_lie_apart_from_each_other_and_the_probe_and_inside_the_image(qtbot, banner):
    feed = _feed(qtbot, [100.0, 60.0], [150.0, 40.0])   # the probe resting beside P4
    feed.show_hot_spots(HotSpotLayer(
        (HotSpotMark("P4 8 mm nearer", np.array([80.0, 62.0]), np.array([15.0, 15.0])),
         HotSpotMark("P5 15 mm nearer", arrow_at=np.array([0.0, 30.0]), arrow_way=np.array([-1.0, 0.0])),
         HotSpotMark("P6 20 mm deeper", arrow_at=np.array([30.0, 0.0]), arrow_way=np.array([0.0, -1.0]))),
        banner, False, "found: P1, P2, P3"))
    feed.grab()                                          # one paint
    words = dict(feed.hot_spot_words)
    assert set(words) == {"P4 8 mm nearer", "P5 15 mm nearer", "P6 20 mm deeper", "found: P1, P2, P3"} | (
        {banner} - {""})
    target = feed._target()
    for text, box in words.items():
        assert _inside(box, target), text
    drawn = feed._drawn_boxes(target, target.width() / 192)
    assert len(drawn) > 3                                # the title, the tip, its axis and its depth words
    for text, box in words.items():
        assert all(_overlap(box, other) == 0 for other in drawn), f"{text} over the title or the probe"
        assert all(_overlap(box, other) == 0 for name, other in words.items() if name != text), f"{text} over words"


def test_the_probes_depth_label_turns_left_at_the_right_edge_of_the_image(qtbot):
    feed = _feed(qtbot, [185.0, 60.0], [191.0, 40.0])   # the tip near the right edge
    target = feed._target()
    at, text = feed._depth_label(feed._at(target, target.width() / 192, 185.0, 60.0), target)
    assert text == "114.8 mm" and at.x() >= target.left()
    assert at.x() + feed.fontMetrics().horizontalAdvance(text) <= target.right()
