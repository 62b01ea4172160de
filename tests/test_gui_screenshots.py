"""The screenshot script (python -m snreg_gui.screenshots; snreg_gui.tools.shooter takes the shots): its blank-shot
detector, shots that wait for a frame on their feeds (the trocar wizard's was once all black, taken before the first
frame), and shots taken the moment the screen shows what they are of (the hot spot not found yet on or off screen).
The whole run takes minutes: it is run by hand (see its docstring), not here."""

import numpy as np
import pytest
from PySide6.QtGui import QColor, QImage

from snreg_gui.tools import shooter
from snreg_gui.tools.shooter import UNIFORM_FEED, Shooter, blank_reason, grey_pixels


def test_blank_images_are_told_from_pages_and_frames():
    rng = np.random.default_rng(0)
    black = np.zeros((700, 1024), np.uint8)
    assert "100.0% of the pixels are the one value 0" == blank_reason(black)
    grey_page = np.full((700, 1024), 239, np.uint8)
    assert blank_reason(grey_page) is not None
    text_page = grey_page.copy()
    for row in range(40, 160, 40):                     # three lines of text on a plain page
        text_page[row:row + 10, 20:700:3] = 30
    assert blank_reason(text_page) is None
    caption_on_black = black[:300, :400].copy()
    caption_on_black[5:15, 5:40:2] = 255               # a feed's title and no frame
    assert blank_reason(caption_on_black, UNIFORM_FEED) is not None
    frame = rng.integers(60, 200, (300, 400)).astype(np.uint8)
    assert blank_reason(frame, UNIFORM_FEED) is None
    letterboxed = black[:300, :400].copy()
    letterboxed[75:225] = frame[75:225]                # black bands are not blank
    assert blank_reason(letterboxed, UNIFORM_FEED) is None
    assert blank_reason(np.zeros((0, 0), np.uint8)) == "empty image"


def test_grey_pixels_read_a_qimage_with_padded_rows():
    image = QImage(33, 5, QImage.Format.Format_RGB32)      # 33 grey bytes: rows padded to 36
    image.fill(QColor(200, 200, 200))
    image.setPixelColor(32, 4, QColor(0, 0, 0))
    grey = grey_pixels(image)
    assert grey.shape == (5, 33) and grey[0, 0] == 200 and grey[4, 32] == 0


def _feed_window(qtbot):
    from PySide6.QtWidgets import QVBoxLayout, QWidget

    from snreg_gui.common.feed_view import FeedView
    window = QWidget()
    qtbot.addWidget(window)
    feed = FeedView("left")
    QVBoxLayout(window).addWidget(feed)
    window.show()
    return window, feed


def test_a_shot_waits_for_the_first_frame_on_its_feeds(qtbot, tmp_path):
    """The trocar wizard's shot was all black: taken before its first frame. A shot now waits for one."""
    from PySide6.QtCore import QTimer
    window, feed = _feed_window(qtbot)
    frame = np.random.default_rng(1).integers(0, 255, (120, 160, 3)).astype(np.uint8)
    QTimer.singleShot(2500, lambda: feed.show_frame(frame))         # after the shot's own settling time
    shots = Shooter(tmp_path, [(320, 240)], [])
    shots.shoot("feed", window)
    assert shots.blank == [] and [p.name for p in shots.written] == ["feed-320x240.png"]
    assert blank_reason(grey_pixels(QImage(str(shots.written[0])))) is None


def test_a_feed_without_a_frame_is_reported_blank_or_stops_the_run(qtbot, tmp_path, monkeypatch):
    window, feed = _feed_window(qtbot)
    monkeypatch.setattr(shooter, "FEED_TIMEOUT_S", 0.5)
    with pytest.raises(SystemExit, match="a frame on feed's feeds"):
        Shooter(tmp_path, [(320, 240)], []).shoot("feed", window)
    feed.show_frame(np.zeros((120, 160, 3), np.uint8))                  # a frame, all black
    shots = Shooter(tmp_path, [(320, 240)], [])
    shots.shoot("feed", window)
    assert len(shots.blank) == 1 and "feed 'left'" in shots.blank[0]


@pytest.mark.slow
def test_the_guides_set_shoots_tabs_at_every_size_and_wizard_pages_at_the_first_in_256_colours(qtbot, tmp_path):
    """``--docs`` (issue 35's screenshot set): every tab at 1024x700 and 1366x768, each wizard page at 1024x700 only,
    nothing outside the set, saved with a palette so the set stays small in the repository."""
    window, feed = _feed_window(qtbot)
    feed.show_frame(np.random.default_rng(2).integers(0, 255, (120, 160, 3)).astype(np.uint8))
    shots = Shooter(tmp_path, [(320, 240), (400, 300)], [], docs=True)
    assert shots.wanted("tab-3-review") and shots.wanted("trocar-4-manual")
    assert not shots.wanted("paused-for-calibration") and not shots.wanted("refused-store", "replay-acquisition")
    shots.shoot("tab-1-acquisition", window)
    shots.shoot("stereo-1-setup", window)
    shots.shoot("close-question", window)                               # not in the set: not taken
    assert [p.name for p in shots.written] == ["tab-1-acquisition-320x240.png", "tab-1-acquisition-400x300.png",
                                               "stereo-1-setup-320x240.png"]
    assert all(QImage(str(p)).format() == QImage.Format.Format_Indexed8 for p in shots.written)
    assert shots.blank == []


def test_a_shot_with_a_condition_is_taken_the_moment_the_screen_meets_it_and_the_guide_has_it_at_1366x768(
        qtbot, tmp_path, monkeypatch):
    """The navigation shots wait for the live feed to draw the hot spot not found yet (in the image, or as an edge
    arrow): the shot shows it; the guide's set takes them at the second size only (1366x768 in the real run). A moment
    that never comes stops the run, or, with ``give_up_s``, is said and not taken."""
    from PySide6.QtCore import QTimer

    from snreg_gui.common.feed_view import HotSpotLayer, HotSpotMark
    window, feed = _feed_window(qtbot)
    feed.show_frame(np.full((120, 160, 3), 90, np.uint8))
    mark = HotSpotLayer((HotSpotMark("P4 8 mm deeper", np.array([80.0, 60.0]), np.array([30.0, 20.0])),))
    QTimer.singleShot(2500, lambda: feed.show_hot_spots(mark))         # after the shot's own settling time
    shots = Shooter(tmp_path, [(320, 240), (400, 300)], [], docs=True)
    shots.shoot("navigation-on-screen", window, when=lambda: feed.hot_spots is not None, what="the mark")
    assert [p.name for p in shots.written] == ["navigation-on-screen-400x300.png"]
    pixels = QImage(str(shots.written[0])).convertToFormat(QImage.Format.Format_RGB888)
    rgb = np.frombuffer(pixels.constBits(), np.uint8, pixels.bytesPerLine() * pixels.height()).reshape(
        pixels.height(), pixels.bytesPerLine())[:, :3 * pixels.width()].reshape(pixels.height(), pixels.width(), 3)
    target = np.all(np.abs(rgb.astype(int) - [80, 200, 255]) < 40, axis=2)      # the mark's colour, drawn
    assert target.sum() > 50
    monkeypatch.setattr(shooter, "WHEN_TIMEOUT_S", 0.5)
    with pytest.raises(SystemExit, match="the arrow"):
        shots.shoot("navigation-off-screen", window, when=lambda: False, what="the arrow")
    shots.shoot("navigation-off-screen", window, when=lambda: False, what="edge arrow", give_up_s=0.3)
    assert len(shots.written) == 1 and shots.missed == ["navigation-off-screen-400x300: no edge arrow within 0 s"]
