"""The app starts offscreen (pytest-qt), with and without the demo rig."""

import numpy as np
import pytest
from PySide6.QtWidgets import QLabel

from snreg_gui.app import MainWindow
from snreg_gui.common.feed_view import FeedView
from snreg_gui.window_closing import end_question

pytestmark = pytest.mark.realtime            # a live feed at its own pace: runs alone (tests/conftest.py)


@pytest.mark.slow
def test_main_window_starts_in_demo_mode(qtbot, tmp_path):
    window = MainWindow(str(tmp_path / "demo.h5"), demo=True)
    qtbot.addWidget(window)
    with qtbot.waitExposed(window):
        window.show()
    path = str(tmp_path / "demo.h5")
    assert window.windowTitle().endswith(f" - demo - {path}")         # the session named in full (issue 35)
    assert window.statusBar().currentMessage().startswith("demo mode: no hardware")
    assert window.statusBar().currentMessage().endswith(f"recording into {path}")
    first_frame = f"demo mode: no hardware; recording into {path}"       # once the first frame is processed
    def first_frame_processed():
        assert window.statusBar().currentMessage() == first_frame            # on a timeout: what it said

    qtbot.waitUntil(first_frame_processed, timeout=60_000)
    assert window.acquisition.isVisible()
    window.shutdown()


def test_a_screen_replaced_in_the_acquisition_tab_is_hidden_at_once(qtbot):
    window = MainWindow()
    qtbot.addWidget(window)
    with qtbot.waitExposed(window):
        window.show()
    placeholder = window.tabs.widget(0).layout().itemAt(0).widget()
    window._show_in_acquisition_tab(QLabel("the new screen"))
    assert not placeholder.isVisible()              # before any event loop turn (deleteLater waits for one)
    window.shutdown()


def test_main_window_without_demo_says_what_to_do(qtbot):
    window = MainWindow()
    qtbot.addWidget(window)
    assert window.statusBar().currentMessage() == "ready"
    placeholder = window.tabs.widget(0).layout().itemAt(0).widget()
    assert "--demo" in placeholder.text() and "Select cameras and IMU" in placeholder.text()
    window.shutdown()


def test_painting_does_not_run_down_the_reference_count_of_none(qtbot):
    """PySide6 6.12.0 on Python 3.11 drops a reference to None on every void QPainter call, which
    crashes a long video session (bool_dealloc); pyproject pins PySide6-Essentials below 6.12."""
    import sys

    from PySide6.QtGui import QColor, QImage, QPainter

    target = QImage(8, 8, QImage.Format.Format_RGB32)
    painter = QPainter(target)
    before = sys.getrefcount(None)
    for _ in range(1000):
        painter.setPen(QColor("red"))
    painter.end()
    assert sys.getrefcount(None) >= before - 10


def test_the_feed_view_paints_the_frame_and_its_layers(qtbot):
    view = FeedView("left")
    qtbot.addWidget(view)
    view.resize(400, 225)
    frame = np.full((90, 160, 3), 40, np.uint8)
    view.show_frame(frame)
    scale = 400 / 160                                         # the frame fills the widget: same aspect

    def pixel(x, y):                                          # image pixel (x, y) as painted, RGB
        colour = view.grab().toImage().pixelColor(int((x + 0.5) * scale), int((y + 0.5) * scale))
        return colour.red(), colour.green(), colour.blue()

    assert pixel(80, 45) == (40, 40, 40) and view.frame is frame and view.image_size == (160, 90)
    view.show_points(np.array([[20.0, 20.0], [120.0, 60.0]]))
    red, green, _ = pixel(20, 20)
    assert red > 200 and green < 100                         # the first point in red
    red, green, _ = pixel(120, 60)
    assert green > 200 and red < 50                           # the others in green
    view.show_heat(np.dstack([np.zeros((2, 2, 2), np.uint8), np.full((2, 2), 255, np.uint8),
                              np.array([[255, 0], [0, 0]], np.uint8)]))
    assert pixel(140, 70)[2] == 40 and pixel(5, 80)[2] == 40  # transparent cells leave the frame alone
    view.show_points(None)
    assert pixel(20, 20)[2] > 200                             # an opaque cell covers its quarter of the frame
    view.clear("left: no snapshot")
    assert view.frame is None and view.title == "left: no snapshot" and pixel(80, 45) == (0, 0, 0)


def test_the_question_on_close_names_nodes_landmarks_and_the_file():
    assert end_question(4, 3, "/p/x.h5") == "4 nodes and 3 landmarks stored, all saved in /p/x.h5; end the session?"
    assert end_question(1, 1, "/p/x.h5") == "1 node and 1 landmark stored, all saved in /p/x.h5; end the session?"
    assert end_question(0, 0, "x.h5").startswith("0 nodes and 0 landmarks stored")
