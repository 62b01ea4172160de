"""Screenshots of every tab and every wizard page of the demo, at 1024x700 and 1366x768, for a person to look at.

    xvfb-run -a -s "-screen 0 1920x1080x24" .venv/bin/python -m snreg_gui.screenshots -o screenshots/
    QT_QPA_PLATFORM=offscreen .venv/bin/python -m snreg_gui.screenshots -o screenshots/ --only trocar
    QT_QPA_PLATFORM=offscreen .venv/bin/python -m snreg_gui.screenshots --docs -o docs/images/   # the guide's set

``--camera`` picks the demo (default surgery: the camera slides and turns between nodes, its insertion tracked; still:
the thesis' phantom). ``--docs`` takes the set the technician's guide shows (issue 35: every tab of the surgery demo
with nothing cut, at both sizes; each wizard page at the smallest, where a cut would show first), saved with a
palette of 256 colours so the set stays small in the repository.

Why: offscreen tests prove behaviour, not that a screen reads well. This drives the demo as an operator would
(auto-store the four phantom nodes, register against the phantom SPECT, go through both calibration wizards
page by page on their rendered scenes and finish them, refuse a store with the IMU unplugged, ask on close,
review the session) and saves each screen as ``<name>-<W>x<H>.png``. Under X (Xvfb) a shot is what the X
server shows; offscreen, the widget's own rendering. A shot is taken only once every camera feed on it shows a
frame, and the run fails (exit status 1) when any shot is blank: the whole image, or a feed's area, one flat
colour (:func:`blank_reason`), as the trocar wizard's shot once was, taken before its first frame.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PySide6.QtCore import QPoint, QSettings, Qt
from PySide6.QtGui import QImage, QPainter
from PySide6.QtWidgets import QApplication, QMessageBox, QWidget, QWizard

from snreg_gui.tools.layout_check import SCREEN_SIZES

SIZES = SCREEN_SIZES[:2]           # 1024x700 and 1366x768: where a cut shows first
FEED_TIMEOUT_S = 180.0            # a rendered scene's first frame, on a loaded machine
STORE_TIMEOUT_S = 900.0           # the demo's four nodes auto-stored, on a loaded machine
SURGERY_FIXES = 20                # fixes per node in the surgery demo's shots
SURGERY_SCALE = 0.25              # its cameras' resolution, of the thesis' 1920x1080
UNIFORM_IMAGE = 0.999            # a whole shot this uniform is blank (a page of text is far from it)
UNIFORM_FEED = 0.985             # a feed's area this uniform shows no frame (a caption on black)
# the shots, by the part of the run that takes them (--only picks parts of these names)
PHASES = {"tabs": ("tab-1-acquisition", "tab-2-registration", "tab-3-review"),
          "stereo": ("stereo-1-setup", "stereo-2-capture", "paused-for-calibration", "stereo-3-calibrate",
                     "stereo-4-save", "stereo-5-applied"),
          "trocar": ("trocar-1-method", "trocar-2-pivot", "trocar-2-tissue", "trocar-3-arc", "trocar-4-manual",
                     "trocar-5-summary", "trocar-6-applied"),
          "refusal": ("refused-store", "close-question"),
          "replay": ("replay-acquisition",)}
# --docs: the tabs at every size, these wizard pages at the first size only
DOCS_TABS = PHASES["tabs"]
DOCS_PAGES = ("stereo-1-setup", "stereo-2-capture", "stereo-3-calibrate", "stereo-4-save", "trocar-1-method",
              "trocar-2-pivot", "trocar-2-tissue", "trocar-3-arc", "trocar-4-manual", "trocar-5-summary")


def blank_reason(grey: np.ndarray, uniform: float = UNIFORM_IMAGE, tolerance: int = 6) -> str | None:
    """Why a (H, W) 8-bit grey image counts as blank, or None: more than ``uniform`` of its pixels within
    ``tolerance`` of its median (all black, all grey, a caption on black)."""
    grey = np.asarray(grey)
    if grey.size == 0:
        return "empty image"
    median = float(np.median(grey))
    flat = float(np.mean(np.abs(grey.astype(np.int16) - median) <= tolerance))
    return f"{flat:.1%} of the pixels are the one value {median:.0f}" if flat > uniform else None


def grey_pixels(image: QImage) -> np.ndarray:
    """(H, W) uint8 grey levels of a QImage."""
    grey = image.convertToFormat(QImage.Format.Format_Grayscale8)
    width, height, stride = grey.width(), grey.height(), grey.bytesPerLine()
    if width == 0 or height == 0:
        return np.zeros((0, 0), np.uint8)
    return np.frombuffer(grey.constBits(), np.uint8, stride * height).reshape(height, stride)[:, :width].copy()


def _spin(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        QApplication.processEvents()
        time.sleep(0.01)


def wait_until(condition, timeout_s: float, what: str) -> None:
    """Run the event loop until ``condition()`` holds; SystemExit naming ``what`` after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            raise SystemExit(f"screenshots: gave up waiting for {what} after {timeout_s:.0f} s")
        QApplication.processEvents()
        time.sleep(0.01)


class Shooter:
    """Saves shots of a widget (or a window with a box over it) at each size and keeps the blank ones' reasons."""

    def __init__(self, out: Path, sizes, only: list[str], docs: bool = False):
        self.out, self.sizes, self.only, self.docs = out, sizes, only, docs
        self.x11 = QApplication.instance().platformName() == "xcb"
        self.written: list[Path] = []
        self.blank: list[str] = []

    def wanted(self, *names: str) -> bool:
        """Whether any of these shots is asked for (``--only``: parts of their names; ``--docs``: the guide's set;
        neither: all)."""
        if self.docs and not any(name in DOCS_TABS + DOCS_PAGES for name in names):
            return False
        return not self.only or any(part in name for name in names for part in self.only)

    def shoot(self, name: str, widget: QWidget, box: QWidget | None = None, centre_box: bool = True) -> None:
        """``widget`` resized to each size, once its feeds show frames; ``box`` over it, centred on it (as a message
        box opens) or where it stands."""
        if not self.wanted(name):
            return
        from snreg_gui.common.feed_view import FeedView
        for width, height in self.sizes if not self.docs or name in DOCS_TABS else self.sizes[:1]:
            widget.move(0, 0)                        # all of it on the screen, whatever its size
            widget.resize(width, height)
            _spin(0.8)
            if box is not None and centre_box:
                box.move(widget.mapToGlobal(widget.rect().center()) - box.rect().center())
            feeds = [f for f in widget.findChildren(FeedView) if f.isVisible()]
            wait_until(lambda: all(f._image is not None for f in feeds), FEED_TIMEOUT_S, f"a frame on {name}'s feeds")
            _spin(0.7)
            image = self._grab(widget, box)
            path = self.out / f"{name}-{width}x{height}.png"
            saved = image.convertToFormat(QImage.Format.Format_Indexed8, Qt.ImageConversionFlag.DiffuseDither) \
                if self.docs else image
            saved.save(str(path), quality=0 if self.docs else -1)          # 0: PNG's strongest compression
            self.written.append(path)
            self._check(path, image, widget, feeds)
            print(f"wrote {path} ({image.width()}x{image.height()})", flush=True)

    def _grab(self, widget: QWidget, box: QWidget | None) -> QImage:
        widget.raise_()
        widget.activateWindow()
        if box is not None:
            box.raise_()
        _spin(0.3)
        if self.x11:                                 # what the X server shows: the window and any box over it
            top = widget.mapToGlobal(QPoint(0, 0))
            return widget.screen().grabWindow(0, top.x(), top.y(), widget.width(), widget.height()).toImage()
        image = widget.grab().toImage().convertToFormat(QImage.Format.Format_RGB32)
        if box is not None:
            painter = QPainter(image)
            corner = box.mapToGlobal(QPoint(0, 0)) - widget.mapToGlobal(QPoint(0, 0))
            painter.drawPixmap(corner, box.grab())
            painter.end()
        return image

    def _check(self, path: Path, image: QImage, widget: QWidget, feeds) -> None:
        grey = grey_pixels(image)
        problems = [reason for reason in [blank_reason(grey)] if reason]
        for feed in feeds:
            corner = feed.mapTo(widget, QPoint(0, 0))
            area = grey[corner.y():corner.y() + feed.height(), corner.x():corner.x() + feed.width()]
            reason = blank_reason(area, UNIFORM_FEED)
            if reason:
                problems.append(f"feed '{feed.title}': {reason}")
        for reason in problems:
            self.blank.append(f"{path.name}: {reason}")
            print(f"BLANK {path.name}: {reason}", flush=True)


def _store_and_register(shots: Shooter, window) -> None:
    from snreg.demo.scene import NODE_CENTRES_MM
    screen, panel = window.acquisition, window.registration
    screen.auto_store.setChecked(True)
    wait_until(lambda: screen.nodes.rowCount() == len(NODE_CENTRES_MM), STORE_TIMEOUT_S, "the four nodes to be stored")
    screen.auto_store.setChecked(False)
    shots.shoot("tab-1-acquisition", window)
    window.tabs.setCurrentWidget(panel)
    wait_until(lambda: panel.preop_box.nodes is not None, 60, "the phantom SPECT")
    panel.auto_rerun.setChecked(False)
    panel.run_button.click()
    wait_until(lambda: panel.last_result is not None and not panel.busy, 120, "the registration")
    shots.shoot("tab-2-registration", window)
    window.tabs.setCurrentWidget(window._acquisition_tab)


def _stereo_wizard(shots: Shooter, window) -> None:
    from snreg.calibration.stereo import MIN_VIEWS
    window.wizards.stereo()
    wizard = window.wizards.active
    shots.shoot("stereo-1-setup", wizard)
    wizard.next()
    capture = wizard.capture_page
    capture.auto_capture.setChecked(True)
    wait_until(lambda: len(capture.views) >= MIN_VIEWS + 1, 400, "the stereo views to be captured")
    capture.auto_capture.setChecked(False)
    shots.shoot("stereo-2-capture", wizard)
    wizard.resize(700, 560)
    wizard.move(0, 130)                               # beside the acquisition side panel, which says it is paused
    shots.shoot("paused-for-calibration", window, box=wizard, centre_box=False)
    wizard.next()
    wait_until(lambda: wizard.calibrate_page.isComplete(), 300, "the stereo calibration")
    shots.shoot("stereo-3-calibrate", wizard)
    wizard.next()
    shots.shoot("stereo-4-save", wizard)
    wizard.button(QWizard.WizardButton.FinishButton).click()
    wait_until(lambda: window.wizards.active is None, 60, "the stereo wizard to finish")
    _shoot_calibration_box(shots, window, "stereo-5-applied")


def _shoot_calibration_box(shots: Shooter, window, name: str) -> None:
    """The box that says where the calibration was saved and that it is applied (or offers to re-express)."""
    wait_until(lambda: window.calibration_notice is not None or window.calibration_prompt is not None, 30,
               f"the box after {name}")
    box = window.calibration_prompt or window.calibration_notice
    shots.shoot(name, window, box=box)
    keep = [b for b in box.buttons() if box.buttonRole(b) == QMessageBox.ButtonRole.RejectRole]
    (keep or box.buttons())[0].click()
    _spin(0.5)


def _trocar_wizard(shots: Shooter, window) -> None:
    window.wizards.trocar()
    wizard = window.wizards.active
    shots.shoot("trocar-1-method", wizard)
    if not shots.wanted(*PHASES["trocar"][1:]):
        return wizard.reject()
    wizard.next()                                    # pivot (recommended)
    page = wizard.pivot_page
    wait_until(lambda: len(page.samples) >= 3, FEED_TIMEOUT_S, "the pivot page's first samples")
    shots.shoot("trocar-2-pivot", wizard)
    if not shots.wanted(*PHASES["trocar"][2:]):
        return wizard.reject()
    wizard.back()
    wizard.method_page.tissue_button.setChecked(True)
    wizard.next()
    page = wizard.tissue_page
    wait_until(lambda: len(page.samples) >= 3, FEED_TIMEOUT_S, "the tissue page's first samples")
    shots.shoot("trocar-2-tissue", wizard)
    wizard.back()
    wizard.method_page.arc_button.setChecked(True)
    wizard.next()
    shots.shoot("trocar-3-arc", wizard)
    wizard.back()
    wizard.method_page.manual_button.setChecked(True)
    wizard.next()
    shots.shoot("trocar-4-manual", wizard)
    wizard.next()
    shots.shoot("trocar-5-summary", wizard)
    wizard.button(QWizard.WizardButton.FinishButton).click()
    wait_until(lambda: window.wizards.active is None, 60, "the trocar wizard to save and finish")
    _shoot_calibration_box(shots, window, "trocar-6-applied")


def _refusal_and_close(shots: Shooter, window) -> None:
    screen = window.acquisition                      # a new screen since acquisition restarted
    window.rig._simulator.kill()                     # the IMU unplugged: its samples stop
    wait_until(lambda: "IMU is stale" in screen.store_reason.text(), 60, "the IMU to go stale")
    screen.request_store("F5")                       # the foot pedal
    wait_until(lambda: screen.store_status.text().startswith("Refused (F5)"), 10, "the refusal")
    shots.shoot("refused-store", window)
    window.close()
    wait_until(lambda: window.close_prompt is not None, 10, "the question on close")
    shots.shoot("close-question", window, box=window.close_prompt)
    [keep] = [b for b in window.close_prompt.buttons() if b.text() == "Keep recording"]
    keep.click()


def open_review(window, timeout_s: float = 120.0):
    """The window's recorded session closed and opened in its Review tab (the first call; later ones show the tab),
    once read: its nodes listed, the IMU fused, its video opened. Returns the review screen; SystemExit naming what
    did not come after ``timeout_s`` (the layout tests open the review the same way)."""
    if window.session is not None:
        path = window.session.path
        window.pause_acquisition()
        window.session.close()
        window.session = None
        window.open_for_review(path)
    review = window.review
    window.tabs.setCurrentWidget(review)
    wait_until(lambda: review.node_table.rowCount() > 0 and not review.status.text().startswith(("loading", "fusing")),
               timeout_s, "the review")
    wait_until(lambda: review.scrubber.video is not None, timeout_s, "the review's video")
    return review


def _review(shots: Shooter, window) -> None:
    path = window.session.path
    review = open_review(window)
    review.node_table.selectRow(1)                   # its recorded pair at the store fills the two feeds
    wait_until(lambda: review.snapshots.left_view.title.startswith("left: frame"), 60, "the node's recorded pair")
    shots.shoot("tab-3-review", window)
    if shots.wanted(*PHASES["replay"]):
        window.replay(path, 1.0)                     # the session just recorded, played back into a new one
        window.tabs.setCurrentWidget(window._acquisition_tab)
        wait_until(lambda: window.acquisition.nodes.rowCount() == 0 and window.acquisition._last_result is not None,
                   120, "the replay's first frame")
        _spin(3.0)
        shots.shoot("replay-acquisition", window)


def _size(text: str) -> tuple[int, int]:
    width, height = text.lower().split("x")
    return int(width), int(height)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snreg_gui.screenshots", description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="screenshots", help="folder for the PNG files")
    parser.add_argument("--sizes", default=",".join(f"{w}x{h}" for w, h in SIZES),
                        help="window sizes, e.g. 1024x700,1920x1080")
    parser.add_argument("--only", default="", help="comma-separated parts of shot names (e.g. trocar,tab-1)")
    parser.add_argument("--camera", choices=("surgery", "still"), default="surgery",
                        help="the demo shown: surgery (the camera moves between nodes) or still (the thesis' phantom)")
    parser.add_argument("--docs", action="store_true",
                        help="the technician's guide's set: tabs at every size, wizard pages at the first, 256 colours")
    args = parser.parse_args(argv)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    app = QApplication.instance() or QApplication(sys.argv[:1])
    shots = Shooter(out, [_size(s) for s in args.sizes.split(",")], [p for p in args.only.split(",") if p], args.docs)
    from snreg.demo.rig import DemoRig
    from snreg.demo.scene import Schedule
    from snreg_gui.app import MainWindow

    work = Path(tempfile.mkdtemp(prefix="snreg-screens-"))     # the demo session, its video and SPECT: removed
    settings = QSettings(str(work / "settings.ini"), QSettings.Format.IniFormat)
    # the still phantom rests 60 frames per node (a short run); the surgery camera's tour follows its IMU's real-time
    # motion, so it keeps the rests a person gets, rendered at a quarter of the thesis resolution and a node stored
    # from fewer fixes (at half the resolution and 60 fixes a loaded machine stored no node in 15 minutes)
    if args.camera == "surgery":
        window = MainWindow(str(work / "demo.h5"), demo=True, rig=DemoRig(camera="surgery", scale=SURGERY_SCALE),
                            settings=settings, fixes_per_node=SURGERY_FIXES)
    else:
        window = MainWindow(str(work / "demo.h5"), demo=True, rig=DemoRig(schedule=Schedule(rest_frames=60)),
                            settings=settings)
    window.resize(*shots.sizes[0])
    window.show()
    try:
        stored = shots.wanted(*PHASES["tabs"], *PHASES["refusal"])
        if stored:
            _store_and_register(shots, window)
        if shots.wanted(*PHASES["stereo"]):
            _stereo_wizard(shots, window)
        if shots.wanted(*PHASES["trocar"]):
            _trocar_wizard(shots, window)
        if shots.wanted(*PHASES["refusal"]):
            _refusal_and_close(shots, window)
        if stored and shots.wanted("tab-3-review", *PHASES["replay"]):
            _review(shots, window)
    finally:
        window._end_confirmed = True              # no question on close: the run is over
        window.shutdown()
        app.processEvents()
        settings.sync()          # written now, so nothing rewrites the folder once it is deleted
        shutil.rmtree(work, ignore_errors=True)
    print(f"{len(shots.written)} screenshots in {out}; {len(shots.blank)} blank", flush=True)
    for reason in shots.blank:
        print(f"blank: {reason}", file=sys.stderr)
    return 1 if shots.blank or not shots.written else 0
