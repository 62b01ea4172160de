"""The app starts offscreen (pytest-qt), with and without the demo rig."""

from PySide6.QtWidgets import QLabel

from snreg_gui.app import MainWindow


def test_main_window_starts_in_demo_mode(qtbot, tmp_path):
    window = MainWindow(str(tmp_path / "demo.h5"), demo=True)
    qtbot.addWidget(window)
    with qtbot.waitExposed(window):
        window.show()
    assert "demo" in window.windowTitle()
    assert window.statusBar().currentMessage().startswith("demo mode: no hardware")
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
