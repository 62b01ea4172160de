"""The node view in 3D (pyqtgraph.opengl), with node labels drawn over it, as :class:`NodeView3D`.

Why: the technician turns the scene to see whether the mapped preop nodes sit on the stored ones, and how far each
node's own error reaches. Built only where OpenGL works (:func:`snreg_gui.common.node_views.make_node_view`); items
are made once and only updated; a scene given while the view is hidden is drawn when it is next shown
(:class:`~snreg_gui.common.node_scene.DrawnWhenShown`).
"""

from __future__ import annotations

import functools

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QEvent, QPointF, QRectF, Qt
from PySide6.QtGui import QColor, QFontMetrics, QMatrix4x4, QPainter, QPen, QVector3D
from PySide6.QtWidgets import QLabel, QVBoxLayout, QWidget

from snreg.registration.report import INTRAOP_COLOUR, PAIR_COLOUR, PREOP_COLOUR
from snreg_gui.common.ellipses import ellipsoid_rings
from snreg_gui.common.label_layout import fit_camera, place_labels
from snreg_gui.common.node_scene import (ELLIPSE_ALPHA, LANDMARK_COLOUR, MISSING_COLOUR, DrawnWhenShown, NodeScene,
                                        label_font, xyz_of)

__all__ = ["NodeView3D", "LabelOverlay"]


def _faint(colour: str) -> tuple:
    """``colour`` at :data:`ELLIPSE_ALPHA`, as GL items take it (RGBA floats)."""
    return pg.mkColor(colour).getRgbF()[:3] + (ELLIPSE_ALPHA,)


def _set_lines(item, segments: np.ndarray) -> None:
    """Show ``segments`` (start, end pairs) in a ``mode="lines"`` item; hide it when there are none (an empty array
    is not drawable)."""
    item.setVisible(len(segments) > 0)
    if len(segments):
        item.setData(pos=segments)


class NodeView3D(DrawnWhenShown, QWidget):
    """The scene in a rotatable OpenGL view (pyqtgraph.opengl), a legend above; build it only when
    :func:`~snreg_gui.common.node_views.opengl_available`. Each node's 90 % error ellipsoid is drawn as its three
    principal rings, faint, in the node's colour. The camera fits every node whenever the scene's extent changes, the
    grid lies under the nodes, and the labels are drawn by a plain widget over the GL view (so a ``grab()`` shows
    them too)."""

    kind = "3d"

    def __init__(self, parent=None):
        super().__init__(parent)
        import pyqtgraph.opengl as gl

        self.scene_shown = NodeScene()
        self.view = gl.GLViewWidget()
        self.view.setBackgroundColor("w")
        self.grid = gl.GLGridItem()
        self.grid.setColor((0, 0, 0, 40))
        self.view.addItem(self.grid)
        self.pair_lines = gl.GLLinePlotItem(mode="lines", color=pg.mkColor(PAIR_COLOUR), width=1.5, antialias=True)
        self.preop_dots = gl.GLScatterPlotItem(color=pg.mkColor(PREOP_COLOUR).getRgbF(), size=14, pxMode=True)
        self.missing_dots = gl.GLScatterPlotItem(color=pg.mkColor(MISSING_COLOUR).getRgbF(), size=14, pxMode=True)
        self.intraop_dots = gl.GLScatterPlotItem(color=pg.mkColor(INTRAOP_COLOUR).getRgbF(), size=9, pxMode=True)
        self.landmark_dots = (gl.GLScatterPlotItem(color=_faint(LANDMARK_COLOUR), size=16, pxMode=True),    # CT
                              gl.GLScatterPlotItem(color=pg.mkColor(LANDMARK_COLOUR).getRgbF(), size=9, pxMode=True))
        self.ellipsoids = {side: gl.GLLinePlotItem(mode="lines", color=_faint(colour), width=1.0, antialias=True)
                           for side, colour in (("preop", PREOP_COLOUR), ("missing", MISSING_COLOUR),
                                                ("intraop", INTRAOP_COLOUR))}
        for item in (*self.ellipsoids.values(), self.pair_lines, self.preop_dots, self.missing_dots, self.intraop_dots,
                     *self.landmark_dots):
            item.setGLOptions("translucent")
            self.view.addItem(item)
        self.labels = LabelOverlay(self.view)
        self.view.addItem(_projector_class()(self.labels))
        self.legend = QLabel(self.scene_shown.legend())
        self.legend.setWordWrap(True)           # a long legend (landmarks, an out-of-date result) must not widen the panel
        self._bounds: tuple | None = None
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(2)
        layout.addWidget(self.legend)
        layout.addWidget(self.view, 1)

    def _draw_scene(self, scene: NodeScene) -> None:
        """Draw ``scene`` (visible: :class:`~snreg_gui.common.node_scene.DrawnWhenShown` calls it)."""
        self.legend.setText(scene.legend())
        preop, intraop, segments = xyz_of(scene.preop), xyz_of(scene.intraop), scene.pair_segments()
        marks = np.vstack([xyz_of(scene.preop_landmarks), xyz_of(scene.intraop_landmarks)])
        for item, xyz in zip(self.landmark_dots, (xyz_of(scene.preop_landmarks), xyz_of(scene.intraop_landmarks))):
            item.setData(pos=xyz)
        missing = scene.missing_mask()
        self.preop_dots.setData(pos=preop[~missing])
        self.missing_dots.setData(pos=preop[missing])
        self.intraop_dots.setData(pos=intraop)
        _set_lines(self.pair_lines, segments)
        (preop_centres, preop_cov), (intraop_centres, intraop_cov) = scene.ellipsoids()
        for side, centres, covariances in (
                ("preop", preop_centres[~missing], None if preop_cov is None else preop_cov[~missing]),
                ("missing", preop_centres[missing], None if preop_cov is None else preop_cov[missing]),
                ("intraop", intraop_centres, intraop_cov)):
            _set_lines(self.ellipsoids[side], ellipsoid_rings(centres, covariances))
        preop_texts, intraop_texts = scene.texts()
        self.labels.set_labels(np.vstack([preop, intraop, marks]),
                               preop_texts + intraop_texts + sum(scene.landmark_texts(), []),
                               [MISSING_COLOUR if m else PREOP_COLOUR for m in missing]
                               + [INTRAOP_COLOUR] * len(intraop_texts) + sum(scene.landmark_colours(), []))
        points = np.vstack([preop, intraop, marks])
        bounds = (points.min(axis=0).round(1).tolist(), points.max(axis=0).round(1).tolist()) if len(points) else None
        if bounds != self._bounds:      # refit when the extent changes, not on every run: the user may have turned it
            self._bounds = bounds
            self.fit_to_data()

    def fit_to_data(self) -> None:
        """Centre the camera on the nodes' bounding box, far enough that every node is in view; the grid under
        them, as wide as they spread."""
        scene = self.scene_shown
        points = np.vstack([xyz_of(scene.preop), xyz_of(scene.intraop), xyz_of(scene.preop_landmarks),
                            xyz_of(scene.intraop_landmarks)])
        if not len(points):
            return
        centre, distance = fit_camera(points, fov_deg=self.view.opts["fov"], width=self.view.width(),
                                      height=self.view.height())
        self.view.setCameraPosition(pos=pg.Vector(*centre), distance=distance)
        extent = max(float(np.ptp(points[:, :2], axis=0).max()) * 1.2, 40.0)
        spacing = 10.0 ** np.ceil(np.log10(extent / 20))      # a round spacing, at most 20 squares across
        self.grid.setSize(extent, extent)
        self.grid.setSpacing(spacing, spacing)
        self.grid.resetTransform()
        self.grid.translate(centre[0], centre[1], float(points[:, 2].min()))

    def resizeEvent(self, event) -> None:
        super().resizeEvent(event)
        self.fit_to_data()


class LabelOverlay(QWidget):
    """The node labels over the GL view: a transparent child widget (mouse events pass through to the view) that
    draws what the projector item computed at the last GL paint, placed by
    :func:`~snreg_gui.common.label_layout.place_labels` so none covers another or a marker; a thin line joins a
    label pushed away from its node."""

    def __init__(self, view):
        super().__init__(view)
        self.setAttribute(Qt.WidgetAttribute.WA_TransparentForMouseEvents)
        self.positions = np.zeros((0, 3))
        self.texts: list[str] = []
        self.colours: list[str] = []
        self.font = label_font()
        self.anchors = np.zeros((0, 2))
        self.boxes = np.zeros((0, 4))             # the label rectangles, px in the view (tests, screenshots)
        view.installEventFilter(self)
        self.setGeometry(view.rect())

    def eventFilter(self, watched, event) -> bool:
        if event.type() == QEvent.Type.Resize:
            self.setGeometry(watched.rect())
        return False

    def set_labels(self, positions, texts: list[str], colours: list[str]) -> None:
        self.positions, self.texts, self.colours = np.asarray(positions, float).reshape(-1, 3), texts, colours
        self.parentWidget().update()

    def layout_from(self, project: QMatrix4x4) -> None:
        """Project the nodes with ``project`` (model-view-projection then viewport: mm to pixels) and place the
        labels; redraw when anything moved."""
        anchors = np.array([[p.x(), p.y()] for p in (project.map(QVector3D(*map(float, xyz))).toPointF()
                                                    for xyz in self.positions)]).reshape(-1, 2)
        metrics = QFontMetrics(self.font)
        sizes = np.array([[metrics.horizontalAdvance(t) + 4, metrics.height()] for t in self.texts],
                         float).reshape(-1, 2)
        corners = place_labels(anchors, sizes, area=(self.width(), self.height()))
        boxes = np.hstack([corners, corners + sizes])
        if boxes.shape != self.boxes.shape or not np.allclose(boxes, self.boxes, atol=0.5) or \
                not np.allclose(anchors, self.anchors, atol=0.5):
            self.anchors, self.boxes = anchors, boxes
            self.update()

    def paintEvent(self, event) -> None:
        if len(self.boxes) != len(self.texts):
            return
        painter = QPainter(self)
        painter.setRenderHints(QPainter.RenderHint.Antialiasing | QPainter.RenderHint.TextAntialiasing)
        painter.setFont(self.font)
        for (x, y), (left, top, right, bottom), text, colour in zip(self.anchors, self.boxes, self.texts,
                                                                    self.colours):
            nearest = QPointF(min(max(x, left), right), min(max(y, top), bottom))
            if np.hypot(nearest.x() - x, nearest.y() - y) > 12:
                painter.setPen(QPen(QColor(colour), 0.8))
                painter.drawLine(QPointF(x, y), nearest)
            painter.setPen(QColor(colour))
            painter.drawText(QRectF(left, top, right - left, bottom - top), Qt.AlignmentFlag.AlignCenter, text)
        painter.end()


@functools.cache
def _projector_class():
    """A GL item that draws nothing: at each GL paint it hands the current projection to a :class:`LabelOverlay`
    (defined late: pyqtgraph.opengl needs PyOpenGL, imported only when the 3D view is built)."""
    from pyqtgraph.opengl.GLGraphicsItem import GLGraphicsItem

    class LabelProjector(GLGraphicsItem):
        def __init__(self, overlay: LabelOverlay):
            super().__init__()
            self.overlay = overlay

        def paint(self):
            rect = QRectF(self.view().rect())
            to_viewport = QMatrix4x4()
            to_viewport.viewport(rect.left(), rect.bottom(), rect.width(), -rect.height())
            self.overlay.layout_from(to_viewport * self.mvpMatrix())

    return LabelProjector
