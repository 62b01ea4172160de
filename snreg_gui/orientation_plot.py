"""The live yaw/pitch/roll plot of the endoscope IMU over the last seconds.

Why: the operator must see the endoscope is held still while a node is stored (its orientation enters
the trocar position). Three curves are made once and fed from a fixed-size ring of recent values.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg

_COLOURS = {"yaw": "#e6550d", "pitch": "#31a354", "roll": "#3182bd"}


class OrientationPlot(pg.PlotWidget):
    """Yaw, pitch and roll (degrees) against time (seconds ago) over ``span`` values."""

    def __init__(self, span: int = 300):
        super().__init__()
        self.setLabel("left", "angle (deg)")
        self.setLabel("bottom", "frame")
        self.addLegend(offset=(5, 5))
        self._values = np.full((span, 3), np.nan)
        self._x = np.arange(-span + 1, 1)
        self._curves = [self.plot(name=name, pen=pg.mkPen(colour, width=2)) for name, colour in _COLOURS.items()]

    def append(self, euler_deg, redraw: bool = True) -> None:
        """Add one (yaw, pitch, roll) in degrees; redraw now or leave it to a later append."""
        self._values = np.roll(self._values, -1, axis=0)
        self._values[-1] = euler_deg
        if not redraw:
            return
        for curve, column in zip(self._curves, self._values.T):
            curve.setData(self._x, column, connect="finite")
