"""One camera feed with the probe overlay: the image, the tip, the axis and the depth in mm.

Why: at video rate the GUI thread must stay cheap. A pyqtgraph view re-enters Python for every item it
paints (view box, image, markers, text), each time waiting for the GIL the tracking worker holds; this
widget paints the image and the overlay in one call with QPainter, from pixels the worker has projected.
"""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QColor, QImage, QPainter, QPen
from PySide6.QtWidgets import QSizePolicy, QWidget

_TIP_COLOUR = QColor(255, 220, 0)


class FeedView(QWidget):
    """A titled image, scaled to fit with its aspect kept, with a tip marker, an axis line and a depth label."""

    def __init__(self, title: str):
        super().__init__()
        self.title = title
        self._rgb: np.ndarray | None = None       # keeps the pixels of ``_image`` alive
        self._image: QImage | None = None
        self._overlay: np.ndarray | None = None
        self._depth_mm: float | None = None
        self.setMinimumSize(240, 135)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setAttribute(Qt.WidgetAttribute.WA_OpaquePaintEvent)

    def show_frame(self, rgb: np.ndarray, overlay: np.ndarray | None, depth_mm: float | None) -> None:
        """Show an RGB (H, W, 3) uint8 frame; ``overlay`` (2, 2) is the tip and an axis point in its pixels, None to hide."""
        self._rgb = np.ascontiguousarray(rgb)
        height, width = self._rgb.shape[:2]
        self._image = QImage(self._rgb.data, width, height, 3 * width, QImage.Format.Format_RGB888)
        self._overlay, self._depth_mm = overlay, depth_mm
        self.update()

    @property
    def image_size(self) -> tuple[int, int] | None:
        """(width, height) of the frame shown, None before the first."""
        return None if self._image is None else (self._image.width(), self._image.height())

    def _target(self) -> QRectF:
        """Where the image is drawn: centred, as large as fits, aspect kept."""
        w, h = self._image.width(), self._image.height()
        scale = min(self.width() / w, self.height() / h)
        return QRectF((self.width() - w * scale) / 2, (self.height() - h * scale) / 2, w * scale, h * scale)

    def paintEvent(self, event) -> None:
        painter = QPainter(self)
        painter.fillRect(self.rect(), Qt.GlobalColor.black)
        if self._image is not None:
            target = self._target()
            painter.drawImage(target, self._image)
            if self._overlay is not None:
                self._paint_overlay(painter, target)
        painter.setPen(Qt.GlobalColor.white)
        painter.drawText(QPointF(6, 16), self.title)
        painter.end()

    def _paint_overlay(self, painter: QPainter, target: QRectF) -> None:
        scale = target.width() / self._image.width()
        tip, up = (QPointF(target.x() + x * scale, target.y() + y * scale) for x, y in self._overlay)
        painter.setRenderHint(QPainter.RenderHint.Antialiasing)
        painter.setPen(QPen(_TIP_COLOUR, 2))
        painter.drawLine(tip, up)
        painter.setBrush(_TIP_COLOUR)
        painter.drawEllipse(tip, 5, 5)
        if self._depth_mm is not None:
            painter.drawText(tip + QPointF(9, -9), f"{self._depth_mm:.1f} mm")
