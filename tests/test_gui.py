"""The app starts offscreen (pytest-qt)."""

from snreg_gui.app import MainWindow


def test_main_window_starts_in_demo_mode(qtbot):
    window = MainWindow(demo=True)
    qtbot.addWidget(window)
    window.show()
    qtbot.waitExposed(window)
    assert "demo" in window.windowTitle()
    assert window.statusBar().currentMessage() == "demo mode: no hardware"
