"""The acquisition screen's readouts: large numbers that never move the layout, and status lines that are never cut.

Why: the technician reads the tip position, the endoscope angles and the store spread at a glance, from a step
away, while the values change at video rate. A number sits in a label of fixed size (wide enough for its widest
value), so a new value never relayouts the window (a relayout per frame would stall the GUI thread); a status line
word-wraps over the lines it reserves and takes more when its text needs them: never cut, never elided (its advice
at the end was once only in a tooltip at 1366x768). A status line keeps and paints its own text, so a new text is a
repaint of that line, not a relayout of the column. (Filling its own background would also save the repaint of the
group box beneath, but Fusion's group boxes are a shade darker than the window: the lines showed as light bands.)
"""

from __future__ import annotations

import math

from PySide6.QtCore import QEvent, QRect, Qt
from PySide6.QtGui import QFont, QFontDatabase, QPainter
from PySide6.QtWidgets import QGridLayout, QLabel, QSizePolicy, QWidget

NO_VALUE = "\u2014"            # an em dash: no value now (no fix, window not full)
BIG_SCALE = 1.8                # the large numbers' size, times the application font's
SPREAD_GOOD, SPREAD_BAD, SPREAD_NONE = "#1a7f1a", "#c00000", "#808080"
# the tones of the status lines: a warning, a fault that stands out (STALE, LOST, a refusal), good news, paused, idle
WARN, BAD, GOOD, PAUSED, QUIET = ("color: #b35c00", "color: #c00000; font-weight: bold", "color: #006400",
                                  "color: #1f4e9e", "color: #707070")


def big_font(base: QFont) -> QFont:
    """A fixed-pitch bold font ``BIG_SCALE`` times ``base``: digits keep their places as values change."""
    font = QFontDatabase.systemFont(QFontDatabase.SystemFont.FixedFont)
    font.setPointSizeF(base.pointSizeF() * BIG_SCALE)
    font.setBold(True)
    return font


def set_style(widget: QWidget, style: str) -> None:
    """Set a widget's style sheet only when it changes: a style change per frame would cost the GUI thread."""
    if widget.styleSheet() != style:
        widget.setStyleSheet(style)


class BigNumber(QLabel):
    """A large number in a label of fixed size, wide enough for ``widest`` (e.g. "-888.8")."""

    def __init__(self, widest: str, colour: str = ""):
        super().__init__(NO_VALUE)
        self._shown = NO_VALUE         # the text show_value set last
        self.setFont(big_font(self.font()))
        self.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        metrics = self.fontMetrics()
        self.setFixedSize(metrics.horizontalAdvance(widest) + 6, metrics.height() + 2)
        self.set_colour(colour)

    def set_colour(self, colour: str) -> None:
        """Set the text colour (a CSS colour, "" for the default)."""
        set_style(self, f"color: {colour}" if colour else "")

    def show_value(self, value: float | None, decimals: int = 1) -> None:
        """The value with ``decimals`` decimals, or a dash for None or NaN; Qt is not called when the text shown
        stays the same (each call into Qt from the GUI thread may wait for the interpreter lock a worker holds)."""
        missing = value is None or not math.isfinite(value)
        text = NO_VALUE if missing else f"{round(value, decimals) + 0.0:.{decimals}f}"      # never "-0.0"
        if text != self._shown:
            self._shown = text
            self.setText(text)


class StatusLine(QLabel):
    """A status text, word-wrapped: at least ``lines`` lines high (reserved, so a usual text never moves what lies
    below it), and as many more as its text needs at its width; never cut. ``reserve``: a text whose lines are
    reserved too (the longest the line will say, e.g. a warning that may appear), so that it appears without a
    relayout. Its width never drives the layout; its height changes only when a new text needs another number of
    lines (rare, so the layout is not redone at video rate), or grows when the label is first given a width."""

    def __init__(self, text: str = "", lines: int = 1, min_width: int = 160, reserve: str = ""):
        super().__init__()
        # the text is kept and painted here, never given to QLabel: QLabel's setText asks the layouts above it to
        # be redone (its width is not fixed), about 0.8 ms of the GUI thread per new text, several texts a pair
        self._text = text
        self.lines, self.reserve = lines, reserve
        self._reserved: tuple = (None, 0)        # (width and font it was laid out at, the reserve's lines)
        # the font's metrics and the height set, kept: a new text then calls Qt a few times, not a dozen
        # (each call from the GUI thread may wait for the interpreter lock a worker holds)
        self._height = -1
        self._take_font()
        # wrapped when painted: QLabel's own word wrap would give the layout a height-for-width, and a scroll area
        # around it would size to that
        self.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Fixed)
        self.setMinimumWidth(min_width)
        self.setToolTip(text)
        self._set_lines(lines)

    def text(self) -> str:
        return self._text

    def setText(self, text: str) -> None:                       # noqa: N802 (Qt's name)
        if text != self._text:
            self._text = text
            self.setToolTip(text)
            self._set_lines(self.needed_lines())
            self.update()

    def resizeEvent(self, event) -> None:                       # noqa: N802
        super().resizeEvent(event)
        self._set_lines(max(self.shown_lines, self.needed_lines()))     # only grows: no loop with a scroll bar

    def changeEvent(self, event) -> None:                       # noqa: N802
        super().changeEvent(event)
        if event.type() == QEvent.Type.FontChange:               # e.g. a style made it bold: its text takes more room
            self._take_font()
            self._set_lines(self.needed_lines())

    def _take_font(self) -> None:
        """Keep the metrics of the font it has now."""
        self._metrics = self.fontMetrics()
        self._spacing = self._metrics.lineSpacing()
        self._font_key = (self._spacing, self._metrics.averageCharWidth())

    def needed_lines(self, width: int | None = None) -> int:
        """The lines its text (and the reserved text) take at ``width`` px (default: its own), at least ``lines``."""
        width = self.contentsRect().width() if width is None else width
        if width <= 0:
            return self.lines
        key = (width, self._font_key)
        if self._reserved[0] != key:             # the reserve's lines, laid out once per width and font
            self._reserved = (key, self._wrapped_lines(self.reserve, width))
        return max(self.lines, self._reserved[1], self._wrapped_lines(self._text, width))

    def _wrapped_lines(self, text: str, width: int) -> int:
        """The lines ``text`` takes word-wrapped at ``width`` px: a line that fits is not laid out (at video rate the
        wrapping cost the GUI thread a fifth of a millisecond per text)."""
        if not text:
            return 0
        if "\n" not in text and self._metrics.horizontalAdvance(text) <= width:
            return 1
        rect = self._metrics.boundingRect(QRect(0, 0, width, 10_000), Qt.TextFlag.TextWordWrap, text)
        return math.ceil(rect.height() / self._spacing)

    def _set_lines(self, lines: int) -> None:
        self.shown_lines = lines
        height = self._spacing * lines + 4
        if height != self._height:
            self._height = height
            self.setFixedHeight(height)

    def paintEvent(self, event) -> None:                        # noqa: N802
        painter = QPainter(self)
        painter.setPen(self.palette().color(self.foregroundRole()))
        painter.setFont(self.font())
        painter.drawText(self.contentsRect(), Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignTop
                         | Qt.TextFlag.TextWordWrap, self.text())
        painter.end()


class ValueRow(QWidget):
    """Captioned large numbers in ``columns`` columns (0: all in one row), e.g. x, y, z or yaw, pitch, roll."""

    def __init__(self, captions: tuple[str, ...], widest: str, colours: tuple[str, ...] = (), columns: int = 0):
        super().__init__()
        colours = colours or ("",) * len(captions)
        self._colours, self.stale = colours, False
        self.values = [BigNumber(widest, colour) for colour in colours]
        self._captions = [QLabel(caption) for caption in captions]
        for label, colour in zip(self._captions, colours):
            if colour:
                label.setStyleSheet(f"color: {colour}")
        self._grid = QGridLayout(self)
        self._grid.setContentsMargins(0, 0, 0, 0)
        self._grid.setHorizontalSpacing(10)
        self._grid.setVerticalSpacing(0)
        self.columns = 0
        self.set_columns(columns)
        self.setSizePolicy(QSizePolicy.Policy.Fixed, QSizePolicy.Policy.Fixed)

    def set_columns(self, columns: int) -> None:
        """Lay the numbers out in ``columns`` columns (0: one row); each caption sits above its number."""
        columns = columns or len(self.values)
        if columns == self.columns:
            return
        self.columns = columns
        for k, (caption, value) in enumerate(zip(self._captions, self.values)):
            row, column = divmod(k, columns)
            self._grid.addWidget(caption, 2 * row, column, Qt.AlignmentFlag.AlignRight)
            self._grid.addWidget(value, 2 * row + 1, column)

    def show_values(self, values, decimals: int = 1, stale: bool = False) -> None:
        """One value per caption (None or NaN shows a dash); ``values`` None shows dashes. ``stale``: the last values
        of a source gone silent, greyed so they are never read as current (colours set only when this changes)."""
        values = values if values is not None else (None,) * len(self.values)
        if stale != self.stale:
            self.stale = stale
            for label, colour in zip(self.values, self._colours):
                label.set_colour(SPREAD_NONE if stale else colour)
        for label, value in zip(self.values, values):
            label.show_value(None if value is None else float(value), decimals)

    def texts(self) -> list[str]:
        return [label.text() for label in self.values]


def spread_colour(spread_mm: float, limit_mm: float) -> str:
    """The spread's colour against the store guard's limit: green within it, red beyond, grey while the store
    window is not full (NaN)."""
    if not math.isfinite(spread_mm):
        return SPREAD_NONE
    return SPREAD_GOOD if spread_mm <= limit_mm else SPREAD_BAD
