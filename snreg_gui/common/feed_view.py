"""The one widget that shows a camera image: the frame with what lies on it (probe, board corners, coverage, a message).

Why: at video rate the GUI thread must stay cheap. A pyqtgraph view re-enters Python for every item it
paints (view box, image, markers, text), each time waiting for the GIL the tracking worker holds; this
widget paints the image and everything on it in one call with QPainter, from pixels the worker computed.
The acquisition feeds, the wizards' feeds and the review's snapshots all use it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QColor, QImage, QPainter, QPen, QPolygonF
from PySide6.QtWidgets import QSizePolicy, QWidget

from snreg_gui.common.label_layout import place_beside

_TIP_COLOUR = QColor(255, 220, 0)
_TARGET_COLOUR = QColor(80, 200, 255)            # a missing SPECT node: where to look
_STALE_COLOUR = QColor(150, 150, 150)            # ... from a registration that is not current or not confident
_BANNER_COLOUR = QColor(255, 170, 60)
_ARROW_PX = 14.0                                 # an edge arrow's length on screen
_HALO = QColor(0, 0, 0, 210)                     # around a hot spot's words: readable on bright tissue
_TIP_PX = 5.0                                    # the probe tip marker's radius
_DEPTH_AT = QPointF(9, -9)                       # the probe's depth label, from the tip marker
_TITLE_AT = QPointF(6, 16)                       # the feed's title ("left"), its baseline's start


@dataclass(frozen=True, eq=False)
class HotSpotMark:
    """A hot spot not found yet on one feed, in the frame's pixels: its ``text`` ("P4 12 mm deeper") and either its
    90 % region (``centre`` (2,), semi-axes ``axes`` (2,), ``angle_deg``) or, off screen, an arrow at the border
    (``arrow_at`` (2,), unit ``arrow_way`` (2,))."""

    text: str
    centre: np.ndarray | None = None
    axes: np.ndarray | None = None
    angle_deg: float = 0.0
    arrow_at: np.ndarray | None = None
    arrow_way: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class HotSpotLayer:
    """Everything the feed says about the hot spots not found yet: the ``marks``, a ``banner`` over them ("pairing
    not confident: store another node", "updating: ..."), whether they are drawn as current and confident (else
    grey), and the ``note`` of those found ("found: P1, P2")."""

    marks: tuple[HotSpotMark, ...] = ()
    banner: str = ""
    confident: bool = True
    note: str = ""
_POINT_COLOUR, _FIRST_POINT_COLOUR = QColor(0, 230, 90), QColor(255, 60, 60)
_MESSAGE_COLOUR = QColor(255, 90, 90)


class FeedView(QWidget):
    """A titled RGB image, scaled to fit with its aspect kept, and optional layers on it, in image pixels:
    the probe (tip marker, axis line, depth label), points (the first one highlighted), an RGBA heat map
    stretched over the whole image, and a message in the middle."""

    def __init__(self, title: str):
        super().__init__()
        self.title = title
        self._rgb: np.ndarray | None = None       # keeps the pixels of ``_image`` alive
        self._image: QImage | None = None
        self._overlay: np.ndarray | None = None
        self.hot_spots: HotSpotLayer | None = None
        self.hot_spot_words: list[tuple[str, tuple]] = []   # each text the last paint wrote of them, with its box
        self._depth_mm: float | None = None
        self._points: np.ndarray | None = None
        self._heat: np.ndarray | None = None
        self._heat_image: QImage | None = None
        self.message = ""
        self.setMinimumSize(240, 135)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.setAttribute(Qt.WidgetAttribute.WA_OpaquePaintEvent)

    def show_frame(self, rgb: np.ndarray, overlay: np.ndarray | None = None, depth_mm: float | None = None) -> None:
        """Show an RGB (H, W, 3) uint8 frame; ``overlay`` (2, 2) is the tip and an axis point in its pixels, None to hide."""
        self._rgb = np.ascontiguousarray(rgb)
        height, width = self._rgb.shape[:2]
        self._image = QImage(self._rgb.data, width, height, 3 * width, QImage.Format.Format_RGB888)
        self._overlay, self._depth_mm = overlay, depth_mm
        self.update()

    def show_hot_spots(self, layer: HotSpotLayer | None) -> None:
        """Draw the hot spots not found yet (:class:`HotSpotLayer`), None to hide."""
        self.hot_spots = layer
        self.update()

    def show_points(self, points: np.ndarray | None) -> None:
        """Mark points (N, 2) in the frame's pixels (the first in red), None to hide."""
        self._points = None if points is None else np.asarray(points, dtype=float).reshape(-1, 2)
        self.update()

    def show_heat(self, rgba: np.ndarray | None) -> None:
        """Lay an RGBA (h, w, 4) uint8 map over the whole frame (each cell stretched), None to hide."""
        self._heat = None if rgba is None else np.ascontiguousarray(rgba, dtype=np.uint8)
        self._heat_image = None if self._heat is None else QImage(
            self._heat.data, self._heat.shape[1], self._heat.shape[0], 4 * self._heat.shape[1],
            QImage.Format.Format_RGBA8888)
        self.update()

    def show_message(self, text: str) -> None:
        """A short message in the middle of the frame ("" to hide)."""
        self.message = text
        self.update()

    def clear(self, title: str | None = None) -> None:
        """Show no frame (and nothing on it); ``title`` replaces the caption if given."""
        self._rgb = self._image = self._overlay = self._points = self.hot_spots = None
        self.show_heat(None)
        self.message = ""
        if title is not None:
            self.title = title
        self.update()

    @property
    def frame(self) -> np.ndarray | None:
        """The RGB frame shown, None when there is none."""
        return self._rgb

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
        self.hot_spot_words = []
        if self._image is not None:
            target = self._target()
            painter.drawImage(target, self._image)
            if self._heat_image is not None:
                painter.drawImage(target, self._heat_image)
            scale = target.width() / self._image.width()
            if self._points is not None and len(self._points):
                self._paint_points(painter, target, scale)
            if self.hot_spots is not None:
                self._paint_hot_spots(painter, target, scale)
            if self._overlay is not None:
                self._paint_overlay(painter, target, scale)
            if self.message:
                painter.setPen(_MESSAGE_COLOUR)
                painter.drawText(target, Qt.AlignmentFlag.AlignCenter, self.message)
        painter.setPen(Qt.GlobalColor.white)
        painter.drawText(_TITLE_AT, self.title)
        painter.end()

    @staticmethod
    def _at(target: QRectF, scale: float, x: float, y: float) -> QPointF:
        """Widget position of image pixel coordinates (:meth:`_widget_xy`)."""
        return QPointF(*FeedView._widget_xy(target, scale, (x, y)))

    @staticmethod
    def _widget_xy(target: QRectF, scale: float, xy) -> np.ndarray:
        """Widget positions (..., 2) of image pixel coordinates (..., 2), pixel centres at whole numbers; :meth:`_at`
        for one point as a QPointF."""
        return (np.asarray(xy, dtype=float) + 0.5) * scale + (target.x(), target.y())

    def _paint_points(self, painter: QPainter, target: QRectF, scale: float) -> None:
        painter.setRenderHint(QPainter.RenderHint.Antialiasing)
        painter.setPen(Qt.PenStyle.NoPen)
        painter.setBrush(_POINT_COLOUR)
        for x, y in self._points[1:]:
            painter.drawEllipse(self._at(target, scale, x, y), 2.0, 2.0)
        painter.setBrush(_FIRST_POINT_COLOUR)
        painter.drawEllipse(self._at(target, scale, *self._points[0]), 4.5, 4.5)

    def _paint_hot_spots(self, painter: QPainter, target: QRectF, scale: float) -> None:
        """Each mark's region as a dashed ellipse, or an arrow at the border, with its text beside it, clear of the
        title, the probe's marker and words, the banner, the note and the other marks' text; grey when not current or
        not confident; the banner along the top and the found note along the bottom, each wrapped to the image's
        width."""
        layer = self.hot_spots
        colour = _TARGET_COLOUR if layer.confident else _STALE_COLOUR
        painter.setRenderHint(QPainter.RenderHint.Antialiasing)
        painter.setBrush(Qt.BrushStyle.NoBrush)
        metrics = painter.fontMetrics()
        wrap = Qt.TextFlag.TextWordWrap
        words = [said for said in (          # (text, rectangle, alignment, colour), those with something to say
            (layer.banner, target.adjusted(6, 20, -6, 0), Qt.AlignmentFlag.AlignHCenter | Qt.AlignmentFlag.AlignTop,
             _BANNER_COLOUR),
            (layer.note, target.adjusted(6, 0, -6, -4), Qt.AlignmentFlag.AlignLeft | Qt.AlignmentFlag.AlignBottom,
             colour)) if said[0]]
        word_boxes = [_box(painter.boundingRect(where, flags | wrap, text)) for text, where, flags, _ in words]
        taken = np.vstack([self._drawn_boxes(target, scale), np.reshape(word_boxes, (-1, 4))])
        area = (target.left(), target.top(), target.right(), target.bottom())
        for mark in layer.marks:
            painter.setPen(QPen(colour, 2, Qt.PenStyle.DashLine if layer.confident else Qt.PenStyle.DotLine))
            if mark.centre is not None:
                centre = self._at(target, scale, *mark.centre)
                a, b = (max(float(v) * scale, 6.0) for v in mark.axes)
                painter.save()
                painter.translate(centre)
                painter.rotate(mark.angle_deg)
                painter.drawEllipse(QPointF(0.0, 0.0), a, b)
                painter.restore()
                half_w, half_h = _ellipse_half_extent(a, b, mark.angle_deg)
                bounds = (centre.x() - half_w, centre.y() - half_h, centre.x() + half_w, centre.y() + half_h)
            elif mark.arrow_at is not None:
                bounds = self._paint_arrow(painter, self._at(target, scale, *mark.arrow_at), mark, colour)
            else:
                continue
            size = (metrics.horizontalAdvance(mark.text), metrics.height())
            corner = place_beside(bounds, size, taken, area=area)
            _halo_text(painter, QPointF(corner[0], corner[1] + metrics.ascent()), mark.text, colour)
            box = [corner[0], corner[1], corner[0] + size[0], corner[1] + size[1]]
            taken = np.vstack([taken, box])
            self.hot_spot_words.append((mark.text, tuple(box)))
        for (text, where, flags, pen), box in zip(words, word_boxes):
            _halo_text(painter, where, text, pen, flags | wrap)
            self.hot_spot_words.append((text, tuple(box)))

    @staticmethod
    def _paint_arrow(painter: QPainter, tip: QPointF, mark: HotSpotMark, colour: QColor) -> tuple:
        """A filled arrow ending at ``tip`` pointing ``mark.arrow_way``; its bounds (left, top, right, bottom)."""
        way = QPointF(float(mark.arrow_way[0]), float(mark.arrow_way[1]))
        side = QPointF(-way.y(), way.x())
        base = tip - way * _ARROW_PX
        corners = [tip, base + side * (_ARROW_PX / 2), base - side * (_ARROW_PX / 2)]
        painter.setPen(QPen(colour, 2))
        painter.setBrush(colour)
        painter.drawPolygon(QPolygonF(corners))
        painter.setBrush(Qt.BrushStyle.NoBrush)
        xs, ys = [p.x() for p in corners], [p.y() for p in corners]
        return min(xs), min(ys), max(xs), max(ys)

    def _depth_label(self, tip: QPointF, target: QRectF) -> tuple[QPointF, str] | None:
        """Where the probe's depth label is written (its baseline's start) and what: up and right of the tip at
        ``tip``, or up and left where the image ``target`` ends first (it was cut at the right edge)."""
        if self._depth_mm is None:
            return None
        text = f"{self._depth_mm:.1f} mm"
        at = tip + _DEPTH_AT
        width = self.fontMetrics().horizontalAdvance(text)
        if at.x() + width > target.right():
            at = QPointF(tip.x() - _DEPTH_AT.x() - width, at.y())
        return at, text

    def _drawn_boxes(self, target: QRectF, scale: float) -> np.ndarray:
        """(K, 4) left, top, right, bottom widget px of what the feed draws besides the hot spots: its title and the
        probe's overlay (tip marker, points along its axis, depth label); a hot spot's words keep clear of them."""
        boxes = [self._title_box()]
        if self._overlay is not None:       # in numpy: each Qt call here (once ~50 a paint) may wait for the GIL
            ends = self._widget_xy(target, scale, self._overlay)
            centres = ends[0] + (ends[1] - ends[0]) * (np.arange(9) / 8)[:, None]     # the tip, 8 points up the axis
            radii = np.r_[_TIP_PX + 2, np.full(8, 3.0)][:, None]
            boxes += np.hstack([centres - radii, centres + radii]).tolist()
            label = self._depth_label(QPointF(*ends[0]), target)
            if label is not None:
                metrics, (at, text) = self.fontMetrics(), label
                boxes.append([at.x(), at.y() - metrics.ascent(), at.x() + metrics.horizontalAdvance(text),
                              at.y() + metrics.descent()])
        return np.array(boxes, dtype=float)

    def _title_box(self) -> list[float]:
        """The box the feed's title covers (left, top, right, bottom widget px)."""
        metrics = self.fontMetrics()
        return [_TITLE_AT.x(), _TITLE_AT.y() - metrics.ascent(),
                _TITLE_AT.x() + metrics.horizontalAdvance(self.title), _TITLE_AT.y() + metrics.descent()]

    def _paint_overlay(self, painter: QPainter, target: QRectF, scale: float) -> None:
        tip, up = (self._at(target, scale, x, y) for x, y in self._overlay)
        painter.setRenderHint(QPainter.RenderHint.Antialiasing)
        painter.setPen(QPen(_TIP_COLOUR, 2))
        painter.drawLine(tip, up)
        painter.setBrush(_TIP_COLOUR)
        painter.drawEllipse(tip, _TIP_PX, _TIP_PX)
        label = self._depth_label(tip, target)
        if label is not None:
            painter.drawText(*label)


def _ellipse_half_extent(a: float, b: float, angle_deg: float) -> tuple[float, float]:
    """Half the width and height of the box around an ellipse of semi-axes ``a`` (along x before turning) and ``b``
    turned by ``angle_deg``."""
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    return float(np.hypot(a * c, b * s)), float(np.hypot(a * s, b * c))


def _box(rect: QRectF) -> list[float]:
    """A rectangle as (left, top, right, bottom)."""
    return [rect.left(), rect.top(), rect.right(), rect.bottom()]


def _halo_text(painter: QPainter, where, text: str, colour: QColor, flags=None) -> None:
    """``text`` in ``colour`` with a dark rim, at a baseline point or (``flags``) in a rectangle: a hot spot's words
    stay readable over bright tissue and over the grey of an unconfident pairing."""
    for pen, shifts in ((_HALO, ((-1, 0), (1, 0), (0, -1), (0, 1))), (colour, ((0, 0),))):
        painter.setPen(pen)
        for dx, dy in shifts:
            if flags is None:
                painter.drawText(where + QPointF(dx, dy), text)
            else:
                painter.drawText(where.translated(dx, dy), flags, text)
