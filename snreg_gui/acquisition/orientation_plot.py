"""The live yaw/pitch/roll plot of the endoscope IMU over the last seconds.

Why: the operator must see the endoscope is held still while a node is stored (its orientation enters
the trocar position). Three curves are made once and fed from a fixed-size ring of recent values.
The y range is set here, in whole steps, and only when the angles leave it or fill a small part of it
(:func:`y_range`): pyqtgraph's auto-range moved it at nearly every redraw, and each move re-laid its
axis (about 10 ms of the GUI thread per redraw). The curves are redrawn at most ``REDRAW_HZ`` times a second,
whatever the frame rate, the newest sample always shown within a redraw interval (:meth:`OrientationPlot.redraw_due`),
and without pyqtgraph's check for NaN once the ring holds none (issue 36). The legend is the plot's title row, above
the plot area: inside it, it covered the yaw line whenever yaw sat near the top of the range.
"""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg

ANGLE_COLOURS = {"yaw": "#e6550d", "pitch": "#31a354", "roll": "#3182bd"}


MIN_SPAN_DEG = 4.0      # the y axis never zooms in further: sensor noise must not look like motion
RANGE_STEP_DEG = 5.0    # the y range's ends are whole multiples of this
RANGE_PAD_DEG = 1.0     # room kept between the angles and the range's ends when it is set
REDRAW_HZ = 5.0         # enough to see the endoscope held still; more only costs the GUI thread


def y_range(values: np.ndarray, current: tuple[float, float] | None) -> tuple[float, float] | None:
    """The y range (low, high) in degrees to show ``values`` (any shape, NaN ignored) in: ``current`` while every
    value lies within it and it is less than twice as tall as a new one would be; else a new one around them,
    ``RANGE_PAD_DEG`` beyond them, at least ``MIN_SPAN_DEG`` tall, its ends on multiples of ``RANGE_STEP_DEG``.
    None without a finite value and no current range."""
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return current
    low, high = float(finite.min()), float(finite.max())
    middle, half = (low + high) / 2, max((high - low) / 2 + RANGE_PAD_DEG, MIN_SPAN_DEG / 2)
    wanted = (math.floor((middle - half) / RANGE_STEP_DEG) * RANGE_STEP_DEG,
              math.ceil((middle + half) / RANGE_STEP_DEG) * RANGE_STEP_DEG)
    if current is not None and current[0] <= low and high <= current[1] \
            and current[1] - current[0] < 2 * (wanted[1] - wanted[0]):
        return current
    return wanted


def angle_legend() -> str:
    """The plot's legend, one line: each angle's name in its curve's colour after a dash of it."""
    return " &nbsp; ".join(f"<span style='color:{colour}'>&#8212; {name}</span>"
                           for name, colour in ANGLE_COLOURS.items())


class OrientationPlot(pg.PlotWidget):
    """Yaw, pitch and roll (degrees) over the last ``span`` frames.

    Cheap to redraw: the x range is fixed, the y range moves rarely and in whole steps (:func:`y_range`; no closer
    than ``MIN_SPAN_DEG``) and has no SI prefix, the pens are cosmetic (wide pens are slow in Qt's raster engine).
    """

    def __init__(self, span: int = 300):
        super().__init__()
        self.setLabel("left", "angle (deg)")
        self.setLabel("bottom", "frames ago")
        self.getAxis("left").enableAutoSIPrefix(False)
        self.setTitle(angle_legend(), size="9pt")        # above the plot area: no curve ever under it
        self.plotItem.layout.setRowFixedHeight(0, self.plotItem.titleLabel.item.boundingRect().height())
        self.setXRange(-span + 1, 0, padding=0)
        self.enableAutoRange(x=False, y=False)
        self.setMouseEnabled(x=False, y=False)
        self.shown_range: tuple[float, float] | None = None       # the y range set last
        self.range_changes = 0                                     # how often it was set
        self._values = np.full((span, 3), np.nan)     # a ring: row ``_next`` is the oldest
        self._next = 0
        self._x = np.arange(-span + 1, 1)
        self._curves = [self.plot(pen=pg.mkPen(colour)) for colour in ANGLE_COLOURS.values()]
        self.redraws = 0                          # how often the curves were set
        self._undrawn = False                     # samples came since the last redraw
        self._drawn_at: float | None = None       # when (seconds, the caller's clock) the curves were set last

    def append(self, euler_deg) -> None:
        """Add one frame's (yaw, pitch, roll) in degrees, in place (every pair); shown at the next redraw."""
        self._values[self._next] = euler_deg
        self._next = (self._next + 1) % len(self._values)
        self._undrawn = True

    def redraw_due(self, now_s: float) -> bool:
        """Redraw if samples came since the last redraw and it is at least 1 / ``REDRAW_HZ`` ago (``now_s``: seconds
        on any steady clock, the same each call); call it often (every display tick, frames or not), so the newest
        sample is shown within a redraw interval even when the frames stop. True when it redrew."""
        if not self._undrawn or (self._drawn_at is not None and now_s - self._drawn_at < 1.0 / REDRAW_HZ - 1e-3):
            return False
        self._drawn_at = now_s
        self.redraw()
        return True

    @property
    def values(self) -> np.ndarray:
        """(span, 3) yaw, pitch, roll of the last ``span`` frames, oldest first (NaN before the first)."""
        return np.roll(self._values, -self._next, axis=0)

    def redraw(self) -> None:
        """Set the curves to the ring now (NaN, before the first samples or without an IMU, breaks them)."""
        self._undrawn = False
        self.redraws += 1
        values = self.values
        for curve, column in zip(self._curves, values.T):
            finite = bool(np.isfinite(column).all())
            curve.setData(self._x, column, connect="all" if finite else "finite", skipFiniteCheck=finite)
        shown = y_range(values, self.shown_range)
        if shown is not None and shown != self.shown_range:
            self.shown_range = shown
            self.range_changes += 1
            self.setYRange(*shown, padding=0)
