"""One camera feed with the probe overlay: the image, the tip, the axis and the depth in mm.

Why: video-rate display must stay cheap on the GUI thread, so the image and overlay items are made
once and only updated (``setImage(..., autoLevels=False)``, ``setData``), with pixels the worker
has already projected.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg

pg.setConfigOptions(imageAxisOrder="row-major")

_TIP_COLOUR = (255, 220, 0)


class FeedView(pg.GraphicsLayoutWidget):
    """A titled, y-down image view with a tip marker, an axis line and a depth label."""

    def __init__(self, title: str):
        super().__init__()
        self._title = title
        self.view = self.addViewBox(lockAspect=True, invertY=True, enableMouse=False)
        self.image = pg.ImageItem(levels=(0, 255))
        self.axis_line = pg.PlotDataItem(pen=pg.mkPen(_TIP_COLOUR, width=2))
        self.tip = pg.ScatterPlotItem(size=10, brush=pg.mkBrush(*_TIP_COLOUR), pen=pg.mkPen("k"))
        self.depth = pg.TextItem(color=_TIP_COLOUR, anchor=(0, 1))
        for item in (self.image, self.axis_line, self.tip, self.depth):
            self.view.addItem(item)
        self._sized = False

    def show_frame(self, rgb: np.ndarray, overlay: np.ndarray | None, depth_mm: float | None) -> None:
        """Show an RGB frame; ``overlay`` (2, 2) is the tip and an axis point in pixels, None to hide it."""
        self.image.setImage(rgb, autoLevels=False)
        if not self._sized:
            self.view.autoRange(padding=0)
            self._sized = True
        if overlay is None:
            self.tip.setData([], [])
            self.axis_line.setData([], [])
            self.depth.setText("")
            return
        self.tip.setData([overlay[0, 0]], [overlay[0, 1]])
        self.axis_line.setData(overlay[:, 0], overlay[:, 1])
        self.depth.setPos(overlay[0, 0] + 8, overlay[0, 1] - 8)
        self.depth.setText(f"{depth_mm:.1f} mm")
