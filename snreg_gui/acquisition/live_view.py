"""The live half of the acquisition screen: both feeds at the camera's aspect ratio, and the orientation plot with
its numbers in the room they leave.

Why: a feed pane of another shape than the camera's image shows black bands (at 1920x1080 they took a third of the
feeds). Here the feeds are sized to the image itself, side by side or, when that gives clearly larger images (a
narrow window), one above the other with the plot beside them; the plot takes whatever room is left, never less
than its minimum. :func:`arrange` is the rule, a plain function of the pane's size; :func:`plot_pane` puts the
angles and the insertion line beside the plot (the line once lay past the pane's edge at 1024x700).
"""

from __future__ import annotations

from dataclasses import dataclass

from PySide6.QtCore import QRect, QSize, Qt, Signal
from PySide6.QtWidgets import QBoxLayout, QVBoxLayout, QWidget

GAP = 6                     # px between the feeds and around the plot
MIN_FEED_WIDTH = 160
PLOT_MIN = QSize(280, 130)  # the plot with its numbers, below the feeds (wide) or beside them (tall)
STACK_GAIN = 1.05           # stack the feeds only when that makes them at least this much wider


@dataclass(frozen=True)
class Arrangement:
    """Where the left feed, the right feed and the plot go (rects as (x, y, width, height)); ``stacked``: the feeds
    one above the other with the plot on their right, else side by side with the plot below."""

    left: tuple[int, int, int, int]
    right: tuple[int, int, int, int]
    plot: tuple[int, int, int, int]
    stacked: bool


def arrange(width: int, height: int, aspect: float, plot_min: QSize = PLOT_MIN, gap: int = GAP) -> Arrangement:
    """Lay out two feeds of ``aspect`` (image height / width) and the plot in a ``width`` x ``height`` pane: each feed
    exactly the image's shape, as large as the plot's minimum leaves room for."""
    beside = min((width - gap) / 2, (height - gap - plot_min.height()) / aspect)
    stacked = min(width - gap - plot_min.width(), (height - gap) / 2 / aspect)
    if stacked >= STACK_GAIN * beside:
        feed_w = max(int(stacked), MIN_FEED_WIDTH)
        feed_h = round(feed_w * aspect)
        return Arrangement((0, 0, feed_w, feed_h), (0, feed_h + gap, feed_w, feed_h),
                           (feed_w + gap, 0, max(width - feed_w - gap, 0), height), True)
    feed_w = max(int(beside), MIN_FEED_WIDTH)
    feed_h = round(feed_w * aspect)
    x0 = max((width - 2 * feed_w - gap) // 2, 0)           # centred when the height is what limits them
    return Arrangement((x0, 0, feed_w, feed_h), (x0 + feed_w + gap, 0, feed_w, feed_h),
                       (0, feed_h + gap, width, max(height - feed_h - gap, 0)), False)


def plot_pane(plot: QWidget, numbers: QWidget, line: QWidget) -> QWidget:
    """The orientation ``plot`` with a column beside it (below it when the pane is tall): its ``numbers`` above the
    insertion ``line``. The column is as wide as its minimum (the line's), the plot takes the rest; the line keeps its
    height whatever it says, so nothing here moves when a warning appears."""
    pane = QWidget()
    box = QBoxLayout(QBoxLayout.Direction.LeftToRight, pane)
    box.setContentsMargins(0, 0, 0, 0)
    box.addWidget(plot, 1)
    column = QVBoxLayout()
    column.addWidget(numbers, 0, Qt.AlignmentFlag.AlignCenter)
    column.addWidget(line)
    column.addStretch(1)
    box.addLayout(column)
    return pane


class LiveView(QWidget):
    """Places ``left`` and ``right`` (feed views) and ``plot`` (a widget whose layout is a :class:`QBoxLayout`: it is
    turned to stack its parts when the plot is beside the feeds) by :func:`arrange`. Call :meth:`set_aspect` with the
    frames' height / width (16:9 until then)."""

    arranged = Signal(object)          # the new Arrangement, after each layout pass

    def __init__(self, left: QWidget, right: QWidget, plot: QWidget):
        super().__init__()
        self.left, self.right, self.plot = left, right, plot
        for widget in (left, right, plot):
            widget.setParent(self)
        self.aspect = 9 / 16
        self.arrangement: Arrangement | None = None

    def set_aspect(self, aspect: float) -> None:
        """The frames' height / width; lays the feeds out again when it changed."""
        if abs(aspect - self.aspect) > 1e-3:
            self.aspect = aspect
            self._arrange()

    def minimumSizeHint(self) -> QSize:                        # noqa: N802 (Qt's name)
        return QSize(2 * MIN_FEED_WIDTH + GAP, round(MIN_FEED_WIDTH * self.aspect) + GAP + PLOT_MIN.height())

    def sizeHint(self) -> QSize:                               # noqa: N802
        return QSize(960, 700)

    def resizeEvent(self, event) -> None:                      # noqa: N802
        self._arrange()

    def _arrange(self) -> None:
        self.arrangement = arrange(self.width(), self.height(), self.aspect)
        for widget, rect in ((self.left, self.arrangement.left), (self.right, self.arrangement.right),
                             (self.plot, self.arrangement.plot)):
            widget.setGeometry(QRect(*rect))
        layout = self.plot.layout()
        if isinstance(layout, QBoxLayout):
            layout.setDirection(QBoxLayout.Direction.TopToBottom if self.arrangement.stacked
                                else QBoxLayout.Direction.LeftToRight)
        self.arranged.emit(self.arrangement)
