"""Screenshots of every screen of the demo in a real window, for a person to look at (not golden images).

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python -m snreg_gui.screenshots -o screenshots/

Why: offscreen tests prove behaviour, not that a screen reads well. This drives the demo as an operator
would (auto-store the four phantom nodes, register against the phantom SPECT, review the session, open
both calibration wizards on their rendered scenes) and grabs each window from the X screen. Issue 12's states
too: acquisition "paused for calibration" beside an open wizard, the prompt after a new trocar calibration (the
chain a pivot calibration might give, applied as the wizard applies it), a store refused with the IMU simulator
killed, and the question on close.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QApplication, QWidget

from snreg.chain import ChainCalibration
from snreg.demo.rig import DemoRig
from snreg.demo.scene import NODE_CENTRES_MM, Schedule


def wait_until(condition, timeout_s: float, what: str) -> None:
    """Run the event loop until ``condition()`` holds; SystemExit naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise SystemExit(f"screenshots: gave up waiting for {what} after {timeout_s:.0f} s")
        QApplication.processEvents()
        time.sleep(0.01)


def _spin(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        QApplication.processEvents()
        time.sleep(0.01)


def grab(widget: QWidget, path: Path) -> None:
    """The window as the X server shows it (not a widget render), saved as PNG."""
    widget.raise_()
    widget.activateWindow()
    _spin(0.5)
    widget.screen().grabWindow(widget.winId()).save(str(path))
    print(f"wrote {path}")


def grab_screen(path: Path) -> None:
    """The whole X screen (a window and the dialog beside or over it)."""
    _spin(0.5)
    QApplication.primaryScreen().grabWindow(0).save(str(path))
    print(f"wrote {path}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snreg_gui.screenshots", description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="screenshots", help="folder for the PNG files")
    args = parser.parse_args(argv)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    app = QApplication.instance() or QApplication(sys.argv[:1])
    if app.platformName() == "offscreen":
        raise SystemExit("screenshots: needs a real window; run it under xvfb-run (see the module docstring)")
    from snreg_gui.app import MainWindow

    work = Path(tempfile.mkdtemp(prefix="snreg-screens-"))
    settings = QSettings(str(work / "settings.ini"), QSettings.Format.IniFormat)
    window = MainWindow(str(work / "phantom.h5"), demo=True, rig=DemoRig(schedule=Schedule(rest_frames=240)),
                        settings=settings)
    window.resize(1600, 1000)
    window.show()
    screen, panel = window.acquisition, window.registration
    screen.auto_store.setChecked(True)
    wait_until(lambda: screen.nodes.rowCount() == len(NODE_CENTRES_MM), 300, "the four nodes to be stored")
    _spin(1.0)
    grab(window, out / "1-acquisition.png")

    window.tabs.setCurrentWidget(panel)
    wait_until(lambda: panel.preop_box.nodes is not None, 30, "the phantom SPECT")
    panel.alignment.centre_button.click()
    panel.run_button.click()
    wait_until(lambda: panel.last_result is not None, 60, "the registration")
    grab(window, out / "2-registration.png")

    window.tabs.setCurrentWidget(window._acquisition_tab)
    window.wizards.stereo()
    wizard = window.wizards.active
    wizard.next()                                 # setup -> capture
    _spin(6.0)
    grab(wizard, out / "4-stereo-wizard.png")
    wizard.move(0, 150)                           # beside the acquisition's side panel, which says it is paused
    grab_screen(out / "6-paused-for-calibration.png")
    wizard.reject()
    _spin(1.0)

    window.wizards.trocar()
    wizard = window.wizards.active
    wizard.next()                                 # method (pivot) -> live pivot page
    wait_until(lambda: "IMU at frame" in wizard.pivot_page.imu_label.text(), 180, "the pivot scene's first frame")
    _spin(4.0)                                    # (rejecting while it pre-renders would wait on the render)
    grab(wizard, out / "5-trocar-wizard.png")
    new_chain = ChainCalibration.manual(imu_trocar_mm=452.0, trocar_camera_mm=171.5)
    window.session.set_calibration(chain=new_chain)    # what the trocar wizard does when it finishes
    window.apply_chain(new_chain)
    wait_until(lambda: window.calibration_prompt is not None, 10, "the calibration-change prompt")
    grab_screen(out / "7-chain-change-prompt.png")
    [reexpress] = [b for b in window.calibration_prompt.buttons() if b.text().startswith("Re-express")]
    reexpress.click()
    wizard.reject()
    _spin(1.0)

    screen = window.acquisition                   # a new screen since acquisition restarted (auto-store off)
    window.rig._simulator.kill()                  # the IMU unplugged: its samples stop
    wait_until(lambda: "IMU is stale" in screen.store_reason.text(), 60, "the IMU to go stale")
    screen.request_store("F5")                    # the foot pedal
    wait_until(lambda: screen.store_status.text().startswith("Refused (F5)"), 10, "the refusal")
    grab(window, out / "8-refused-store.png")
    window.close()
    wait_until(lambda: window.close_prompt is not None, 10, "the question on close")
    grab_screen(out / "9-close-question.png")
    [keep] = [b for b in window.close_prompt.buttons() if b.text() == "Keep recording"]
    keep.click()

    path = window.session.path
    window.pause_acquisition()
    window.session.close()
    window.session = None
    window.open_for_review(path)
    wait_until(lambda: window.review.node_table.rowCount() == len(NODE_CENTRES_MM), 60, "the review")
    _spin(1.0)
    grab(window, out / "3-review.png")
    window.shutdown()
    return 0

