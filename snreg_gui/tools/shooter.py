"""The screenshot script's camera: shots of a live window at each size, taken once its feeds show frames (and, for
the navigation shots, at the instant the screen shows what they are of), checked for blank areas.

Why apart from :mod:`snreg_gui.tools.screenshots`, which drives the demo as an operator would: this is what any shot
needs, whatever the run; its tests drive it on a window of their own. ``--docs`` (the technician's guide's set,
:data:`DOCS_TABS`, :data:`DOCS_NAVIGATION`, :data:`DOCS_PAGES`) is saved with a palette of 256 colours.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from PySide6.QtCore import QPoint, Qt
from PySide6.QtGui import QImage, QPainter
from PySide6.QtWidgets import QApplication, QWidget

FEED_TIMEOUT_S = 180.0            # a rendered scene's first frame, on a loaded machine
WHEN_TIMEOUT_S = 600.0            # a shot's condition (the surgery camera's tour bringing a hot spot in or out of view)
UNIFORM_IMAGE = 0.999            # a whole shot this uniform is blank (a page of text is far from it)
UNIFORM_FEED = 0.985             # a feed's area this uniform shows no frame (a caption on black)
# --docs, the guide's set: the tabs at every size, the navigation shots at the second (1366x768), the wizard pages
# at the first (1024x700)
DOCS_TABS = ("tab-1-acquisition", "tab-2-registration", "tab-3-review")
DOCS_NAVIGATION = ("navigation-on-screen", "navigation-off-screen")
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


def spin(seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        QApplication.processEvents()
        time.sleep(0.01)


def holds_within(condition, timeout_s: float) -> bool:
    """Run the event loop until ``condition()`` holds (True, returned at once, nothing handled after it) or
    ``timeout_s`` passes (False)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        QApplication.processEvents()
        time.sleep(0.01)
    return True


def wait_until(condition, timeout_s: float, what: str) -> None:
    """Run the event loop until ``condition()`` holds; SystemExit naming ``what`` after ``timeout_s``."""
    if not holds_within(condition, timeout_s):
        raise SystemExit(f"screenshots: gave up waiting for {what} after {timeout_s:.0f} s")


class Shooter:
    """Saves shots of a widget (or a window with a box over it) at each size and keeps the blank ones' reasons."""

    def __init__(self, out: Path, sizes, only: list[str], docs: bool = False):
        self.out, self.sizes, self.only, self.docs = out, sizes, only, docs
        self.x11 = QApplication.instance().platformName() == "xcb"
        self.written: list[Path] = []
        self.blank: list[str] = []
        self.missed: list[str] = []              # shots whose moment never came (``give_up_s``), and why

    def wanted(self, *names: str) -> bool:
        """Whether any of these shots is asked for (``--only``: parts of their names; ``--docs``: the guide's set;
        neither: all)."""
        if self.docs and not any(name in DOCS_TABS + DOCS_NAVIGATION + DOCS_PAGES for name in names):
            return False
        return not self.only or any(part in name for name in names for part in self.only)

    def shoot(self, name: str, widget: QWidget, box: QWidget | None = None, centre_box: bool = True,
              when=None, what: str = "", give_up_s: float | None = None) -> None:
        """``widget`` resized to each size, once its feeds show frames; ``box`` over it, centred on it (as a message
        box opens) or where it stands. ``when``: a condition the live screen must meet at the instant of the shot
        (``what`` says it in words): the shot is taken as soon as it holds, with no event handled in between; the run
        stops when it never does, unless ``give_up_s`` is given: then after that long the shot is not taken, and
        ``missed`` says so (a moment the demo may never bring, said rather than staged)."""
        if not self.wanted(name):
            return
        from snreg_gui.common.feed_view import FeedView
        for width, height in self._sizes_of(name):
            widget.move(0, 0)                        # all of it on the screen, whatever its size
            widget.resize(width, height)
            spin(0.8)
            if box is not None and centre_box:
                box.move(widget.mapToGlobal(widget.rect().center()) - box.rect().center())
            feeds = [f for f in widget.findChildren(FeedView) if f.isVisible()]
            wait_until(lambda: all(f._image is not None for f in feeds), FEED_TIMEOUT_S, f"a frame on {name}'s feeds")
            spin(0.7)
            if when is not None and give_up_s is not None and not holds_within(when, give_up_s):
                self.missed.append(f"{name}-{width}x{height}: no {what or name} within {give_up_s:.0f} s")
                print(f"MISSED {self.missed[-1]}", flush=True)
                continue
            image = self._grab(widget, box, when, what or name)
            path = self.out / f"{name}-{width}x{height}.png"
            saved = image.convertToFormat(QImage.Format.Format_Indexed8, Qt.ImageConversionFlag.DiffuseDither) \
                if self.docs else image
            saved.save(str(path), quality=0 if self.docs else -1)          # 0: PNG's strongest compression
            self.written.append(path)
            self._check(path, image, widget, feeds)
            print(f"wrote {path} ({image.width()}x{image.height()})", flush=True)

    def _sizes_of(self, name: str) -> list[tuple[int, int]]:
        """The sizes ``name`` is shot at: all of them, but with ``--docs`` the wizard pages at the first only and the
        navigation shots at the second only (1366x768)."""
        if not self.docs or name in DOCS_TABS:
            return list(self.sizes)
        return list(self.sizes[1:2] or self.sizes[:1]) if name in DOCS_NAVIGATION else list(self.sizes[:1])

    def _grab(self, widget: QWidget, box: QWidget | None, when=None, what: str = "") -> QImage:
        widget.raise_()
        widget.activateWindow()
        if box is not None:
            box.raise_()
        spin(0.3)
        if when is not None:                         # grabbed right after it holds: nothing runs in between
            wait_until(when, WHEN_TIMEOUT_S, what)
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
