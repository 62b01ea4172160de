"""The screenshot script (python -m snreg_gui.screenshots): its blank-shot detector, and one real shot offscreen
taken only once the trocar wizard's feed shows a frame (it was once all black, taken before the first frame)."""

import numpy as np
import pytest
from PySide6.QtGui import QColor, QImage

from snreg_gui.tools.screenshots import UNIFORM_FEED, blank_reason, grey_pixels, main


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


@pytest.mark.slow
def test_the_trocar_wizard_shot_waits_for_a_frame_and_is_not_blank(qtbot, tmp_path):
    assert main(["-o", str(tmp_path), "--sizes", "640x480", "--only", "trocar-2"]) == 0
    [shot] = tmp_path.glob("*.png")
    assert shot.name == "trocar-2-pivot-640x480.png"
    image = QImage(str(shot))
    assert (image.width(), image.height()) == (640, 480) and blank_reason(grey_pixels(image)) is None
