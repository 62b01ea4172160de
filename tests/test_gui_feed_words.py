"""The words a camera feed writes about the hot spots not found yet (snreg_gui.common.feed_view): each readable, none
over another or over the probe's marker and depth label, none cut by the image's edge, at the size a feed has in a
1024x700 window (issue 36: "P4 8 mm nearer" was written under the probe's "114.8 mm" when the probe rested beside
the hot spot, and a stale banner ran past both edges of the small feed)."""

import numpy as np
import pytest

from snreg.workflow.navigation import NOT_CONFIDENT, UPDATING
from snreg_gui.common.feed_view import FeedView, HotSpotLayer, HotSpotMark
from snreg_gui.registration.panel import OUT_OF_DATE            # the longest banner


def _overlap(a, b) -> float:
    return max(0.0, min(a[2], b[2]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[1], b[1]))


@pytest.mark.parametrize("banner", ["", NOT_CONFIDENT, UPDATING, OUT_OF_DATE])
def test_hot_spot_words_lie_apart_from_each_other_and_the_probe_and_inside_the_image(qtbot, banner):
    feed = FeedView("left")
    qtbot.addWidget(feed)
    feed.resize(292, 164)                                # a feed's size in the 1024x700 window
    feed.show()
    frame = np.full((108, 192, 3), 140, np.uint8)        # the surgery demo's quarter-resolution frame, halved
    feed.show_frame(frame, np.array([[100.0, 60.0], [150.0, 40.0]]), 114.8)    # the probe resting beside P4
    feed.show_hot_spots(HotSpotLayer(
        (HotSpotMark("P4 8 mm nearer", np.array([80.0, 62.0]), np.array([15.0, 15.0])),
         HotSpotMark("P5 15 mm nearer", arrow_at=np.array([0.0, 30.0]), arrow_way=np.array([-1.0, 0.0]))),
        banner, False, "found: P1, P2, P3"))
    feed.grab()                                          # one paint
    words = dict(feed.hot_spot_words)
    assert set(words) == {"P4 8 mm nearer", "P5 15 mm nearer", "found: P1, P2, P3"} | ({banner} - {""})
    target = feed._target()
    image = (target.left(), target.top(), target.right() + 1, target.bottom() + 1)
    for text, box in words.items():
        assert image[0] <= box[0] and box[2] <= image[2] and image[1] <= box[1] and box[3] <= image[3], text
    probe = feed._probe_boxes(target, target.width() / 192)
    assert len(probe) > 2                                # the tip, its axis and its depth words
    for text, box in words.items():
        assert all(_overlap(box, other) == 0 for other in probe), f"{text} over the probe"
        assert all(_overlap(box, other) == 0 for name, other in words.items() if name != text), f"{text} over words"
