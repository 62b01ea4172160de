"""The live yaw/pitch/roll plot of the endoscope IMU over the last seconds.

Why: the operator must see the endoscope is held still while a node is stored (its orientation enters
the trocar position). Three curves are made once and fed from a fixed-size ring of recent values.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg

ANGLE_COLOURS = {"yaw": "#e6550d", "pitch": "#31a354", "roll": "#3182bd"}


MIN_SPAN_DEG = 4.0      # the y axis never zooms in further: sensor noise must not look like motion


class OrientationPlot(pg.PlotWidget):
    """Yaw, pitch and roll (degrees) over the last ``span`` frames.

    Cheap to redraw: the x range is fixed, the y axis zooms no closer than ``MIN_SPAN_DEG`` (so its ticks
    rarely change) and has no SI prefix, the pens are cosmetic (wide pens are slow in Qt's raster engine).
    """

    def __init__(self, span: int = 300):
        super().__init__()
        self.setLabel("left", "angle (deg)")
        self.setLabel("bottom", "frames ago")
        self.getAxis("left").enableAutoSIPrefix(False)
        self.addLegend(offset=(5, 5))
        self.setXRange(-span + 1, 0, padding=0)
        self.enableAutoRange(x=False)
        self.setLimits(minYRange=MIN_SPAN_DEG)
        self.setMouseEnabled(x=False, y=False)
        self._values = np.full((span, 3), np.nan)
        self._x = np.arange(-span + 1, 1)
        self._curves = [self.plot(name=name, pen=pg.mkPen(colour)) for name, colour in ANGLE_COLOURS.items()]

    def append(self, euler_deg) -> None:
        """Add one frame's (yaw, pitch, roll) in degrees; shown at the next :meth:`redraw`."""
        self._values = np.roll(self._values, -1, axis=0)
        self._values[-1] = euler_deg

    def redraw(self) -> None:
        for curve, column in zip(self._curves, self._values.T):
            curve.setData(self._x, column, connect="finite")
