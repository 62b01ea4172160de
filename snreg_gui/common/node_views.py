"""Views of two node sets and their pairs: a 3D OpenGL view, or three 2D projections where OpenGL is missing.

Why: the technician must see at a glance whether the preop nodes (mapped into the intraop frame) sit on the
stored intraop nodes. pyqtgraph's OpenGL view needs PyOpenGL and a working OpenGL context, which remote
desktops, virtual machines and offscreen test runs often lack; :func:`make_node_view` decides at run time and
falls back to :class:`ThreeViewPlot` (axial x-y, coronal x-z, sagittal y-z) rather than ever failing.
Both views take a :class:`NodeScene` through ``show_scene``; items are made once and only updated. Both show a
legend, label each node by its id beside its marker with no label covering another
(:mod:`snreg_gui.common.label_layout`), and fit every node into view, a far one included.

>>> view = make_node_view()            # NodeView3D or ThreeViewPlot; view.kind says which
>>> view.show_scene(NodeScene(mapped_preop_nodes, intraop_nodes, result.pairing))
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QEvent, QPointF, QRectF, Qt
from PySide6.QtGui import (QColor, QFont, QFontMetrics, QGuiApplication, QMatrix4x4, QOffscreenSurface, QOpenGLContext,
                           QPainter, QPen, QVector3D)
from PySide6.QtWidgets import QLabel, QVBoxLayout, QWidget

from snreg.nodes import NodeSet
from snreg.registration.naming import shown_preop_ids
from snreg.registration.report import INTRAOP_COLOUR, PAIR_COLOUR, PREOP_COLOUR, VIEWS
from snreg_gui.common.label_layout import fit_camera, place_labels

__all__ = ["NodeScene", "ThreeViewPlot", "NodeView3D", "make_node_view", "opengl_available", "legend_html",
           "MISSING_COLOUR"]

_NO_GL_PLATFORMS = ("offscreen", "minimal", "vnc")
MISSING_COLOUR = "#ff7f0e"          # a preop node with no intraop partner yet (not found, or not removed yet)


@dataclass(frozen=True)
class NodeScene:
    """What a view shows: preop nodes already in the intraop frame, intraop nodes, and the pairing.

    ``pairing`` is one hot spot (preop index) per intraop node (-1: none), as in ``RegistrationResult``; None: no
    pairs yet.
    ``missing`` is one flag per preop node: left unpaired by the registration (drawn apart); None: not known.
    """

    preop: NodeSet | None = None
    intraop: NodeSet | None = None
    pairing: np.ndarray | None = None
    missing: np.ndarray | None = None

    def pair_segments(self) -> np.ndarray:
        """(2K, 3) mm: intraop node, then its preop node, for each of the K paired intraop nodes."""
        if self.pairing is None or self.preop is None or self.intraop is None:
            return np.zeros((0, 3))
        pairing = np.asarray(self.pairing, dtype=int)
        paired = np.flatnonzero((pairing >= 0) & (pairing < len(self.preop)))[: len(self.intraop)]
        segments = np.empty((2 * len(paired), 3))
        segments[0::2] = self.intraop.xyz[paired]
        segments[1::2] = self.preop.xyz[pairing[paired]]
        return segments

    def missing_mask(self) -> np.ndarray:
        """(N,) bool per preop node: unpaired by the result shown (all False without one)."""
        n = 0 if self.preop is None else len(self.preop)
        if self.missing is None or len(self.missing) != n:
            return np.zeros(n, dtype=bool)
        return np.asarray(self.missing, dtype=bool)

    def texts(self) -> tuple[list[str], list[str]]:
        """(preop, intraop) label texts: the ids, preop ids marked "P:" when they repeat intraop ids."""
        intraop = [] if self.intraop is None else list(self.intraop.ids)
        preop = [] if self.preop is None else shown_preop_ids(self.preop.ids, intraop)
        return preop, intraop


def _xyz(nodes: NodeSet | None) -> np.ndarray:
    return np.zeros((0, 3)) if nodes is None else nodes.xyz


def legend_html() -> str:
    """One line naming what each mark means, in the marks' colours (both views show it above the nodes)."""
    return (f"<span style='color:{PREOP_COLOUR}'>&#9675; preop (mapped)</span> &nbsp; "
            f"<span style='color:{MISSING_COLOUR}'>&#9675; preop, not found yet</span> &nbsp; "
            f"<span style='color:{INTRAOP_COLOUR}'>&#10005; intraop (stored)</span> &nbsp; "
            f"<span style='color:{PAIR_COLOUR}'>&#8212; paired</span>")


def _label_font() -> QFont:
    font = QFont()
    font.setPointSizeF(max(font.pointSizeF(), 9.0))
    return font


class ThreeViewPlot(pg.GraphicsLayoutWidget):
    """Axial (x-y), coronal (x-z) and sagittal (y-z) projections: preop as blue rings (orange when not found yet),
    intraop as red crosses, a legend above; labels beside their markers, moved apart so none covers another."""

    kind = "three-view"

    def __init__(self, parent=None):
        super().__init__(parent)
        self.setBackground("w")
        self.scene_shown = NodeScene()
        self.legend = self.addLabel(legend_html(), row=0, col=0, colspan=len(VIEWS))
        self.plots, self.preop_dots, self.missing_dots, self.intraop_dots, self.pair_lines = [], [], [], [], []
        self._labels: list[tuple[list[pg.TextItem], list[pg.TextItem]]] = []
        self._anchors: list[np.ndarray] = []
        for column, (name, h, v) in enumerate(VIEWS):
            plot = self.addPlot(row=1, col=column, title=f"{name} ({'xyz'[h]}-{'xyz'[v]})")
            plot.setAspectLocked(True)
            plot.showGrid(x=True, y=True, alpha=0.3)
            plot.setLabel("bottom", f"{'xyz'[h]} (mm)")
            plot.setLabel("left", f"{'xyz'[v]} (mm)")
            lines = plot.plot(pen=pg.mkPen(PAIR_COLOUR, width=1.5), connect="pairs")
            preop = pg.ScatterPlotItem(symbol="o", size=13, brush=None, pen=pg.mkPen(PREOP_COLOUR, width=2.5))
            missing = pg.ScatterPlotItem(symbol="o", size=13, brush=None,
                                         pen=pg.mkPen(MISSING_COLOUR, width=2.5, style=Qt.PenStyle.DashLine))
            intraop = pg.ScatterPlotItem(symbol="x", size=12, brush=pg.mkBrush(INTRAOP_COLOUR), pen=None)
            for item in (preop, missing, intraop):
                plot.addItem(item)
            self.plots.append(plot)
            self.pair_lines.append(lines)
            self.preop_dots.append(preop)
            self.missing_dots.append(missing)
            self.intraop_dots.append(intraop)
            self._labels.append(([], []))
            self._anchors.append(np.zeros((0, 2)))
            plot.vb.sigTransformChanged.connect(lambda _=None, k=column: self._place_labels(k))

    def show_scene(self, scene: NodeScene) -> None:
        self.scene_shown = scene
        preop, intraop, segments = _xyz(scene.preop), _xyz(scene.intraop), scene.pair_segments()
        missing = scene.missing_mask()
        preop_texts, intraop_texts = scene.texts()
        for k, (_, h, v) in enumerate(VIEWS):
            self.preop_dots[k].setData(x=preop[~missing, h], y=preop[~missing, v])
            self.missing_dots[k].setData(x=preop[missing, h], y=preop[missing, v])
            self.intraop_dots[k].setData(x=intraop[:, h], y=intraop[:, v])
            self.pair_lines[k].setData(x=segments[:, h], y=segments[:, v], connect="pairs")
            preop_labels, intraop_labels = self._labels[k]
            colours = [MISSING_COLOUR if m else PREOP_COLOUR for m in missing]
            self._sync_labels(self.plots[k], preop_labels, preop_texts, colours)
            self._sync_labels(self.plots[k], intraop_labels, intraop_texts, [INTRAOP_COLOUR] * len(intraop_texts))
            self._anchors[k] = np.vstack([preop[:, [h, v]], intraop[:, [h, v]]])
            self._fit(self.plots[k], self._anchors[k])
            self._place_labels(k)

    @staticmethod
    def _fit(plot, points: np.ndarray) -> None:
        """Show every node with a margin on each side for the labels."""
        if not len(points):
            return
        low, high = points.min(axis=0), points.max(axis=0)
        margin = 0.15 * max(float(np.max(high - low)), 40.0)
        plot.setRange(xRange=(low[0] - margin, high[0] + margin), yRange=(low[1] - margin, high[1] + margin),
                      padding=0)

    @staticmethod
    def _sync_labels(plot, pool: list[pg.TextItem], texts: list[str], colours: list[str]) -> None:
        """Reuse the text items already in ``plot``; add or remove only when the node count changes."""
        while len(pool) < len(texts):
            item = pg.TextItem(anchor=(0, 0))
            item.setFont(_label_font())
            plot.addItem(item, ignoreBounds=True)
            pool.append(item)
        while len(pool) > len(texts):
            plot.removeItem(pool.pop())
        for item, text, colour in zip(pool, texts, colours):
            item.setText(text, color=colour)

    def _place_labels(self, k: int) -> None:
        """Put projection ``k``'s labels beside their markers (in pixels, none covering another), after every
        change of its range or size."""
        preop_labels, intraop_labels = self._labels[k]
        items = preop_labels + intraop_labels
        anchors = self._anchors[k]
        if not items or len(items) != len(anchors):
            return
        box = self.plots[k].vb
        scene_points = [box.mapViewToScene(QPointF(float(x), float(y))) for x, y in anchors]
        pixels = np.array([[p.x(), p.y()] for p in scene_points])
        sizes = np.array([[item.boundingRect().width(), item.boundingRect().height()] for item in items])
        frame = box.sceneBoundingRect()
        corners = place_labels(pixels - [frame.left(), frame.top()], sizes, area=(frame.width(), frame.height()))
        for item, (x, y) in zip(items, corners + [frame.left(), frame.top()]):
            item.setPos(box.mapSceneToView(QPointF(float(x), float(y))))

    def label_texts(self, view: int = 0) -> tuple[list[str], list[str]]:
        """The (preop, intraop) label texts drawn in projection ``view``."""
        preop, intraop = self._labels[view]
        return [item.toPlainText() for item in preop], [item.toPlainText() for item in intraop]

    def label_boxes(self, view: int = 0) -> np.ndarray:
        """(N, 4) scene rectangles (left, top, right, bottom, px) of projection ``view``'s labels, preop first."""
        preop, intraop = self._labels[view]
        rects = [item.sceneBoundingRect() for item in preop + intraop]
        return np.array([[r.left(), r.top(), r.right(), r.bottom()] for r in rects]).reshape(-1, 4)


class NodeView3D(QWidget):
    """The same scene in a rotatable OpenGL view (pyqtgraph.opengl), a legend above; build it only when
    :func:`opengl_available`. The camera fits every node whenever the scene's extent changes, the grid lies under
    the nodes, and the labels are drawn by a plain widget over the GL view (so a ``grab()`` shows them too)."""

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
        for item in (self.pair_lines, self.preop_dots, self.missing_dots, self.intraop_dots):
            item.setGLOptions("translucent")
            self.view.addItem(item)
        self.labels = LabelOverlay(self.view)
        self.view.addItem(_projector_class()(self.labels))
        self.legend = QLabel(legend_html())
        self._bounds: tuple | None = None
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.setSpacing(2)
        layout.addWidget(self.legend)
        layout.addWidget(self.view, 1)

    def show_scene(self, scene: NodeScene) -> None:
        self.scene_shown = scene
        preop, intraop, segments = _xyz(scene.preop), _xyz(scene.intraop), scene.pair_segments()
        missing = scene.missing_mask()
        self.preop_dots.setData(pos=preop[~missing])
        self.missing_dots.setData(pos=preop[missing])
        self.intraop_dots.setData(pos=intraop)
        self.pair_lines.setVisible(len(segments) > 0)
        if len(segments):
            self.pair_lines.setData(pos=segments)
        preop_texts, intraop_texts = scene.texts()
        self.labels.set_labels(np.vstack([preop, intraop]), preop_texts + intraop_texts,
                               [MISSING_COLOUR if m else PREOP_COLOUR for m in missing]
                               + [INTRAOP_COLOUR] * len(intraop_texts))
        points = np.vstack([preop, intraop])
        bounds = (points.min(axis=0).round(1).tolist(), points.max(axis=0).round(1).tolist()) if len(points) else None
        if bounds != self._bounds:      # refit when the extent changes, not on every run: the user may have turned it
            self._bounds = bounds
            self.fit_to_data()

    def fit_to_data(self) -> None:
        """Centre the camera on the nodes' bounding box, far enough that every node is in view; the grid under
        them, as wide as they spread."""
        scene = self.scene_shown
        points = np.vstack([_xyz(scene.preop), _xyz(scene.intraop)])
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
        self.font = _label_font()
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


@functools.cache
def opengl_available() -> bool:
    """True when pyqtgraph.opengl imports (PyOpenGL) and an OpenGL context can be made current here."""
    if QGuiApplication.instance() is None or QGuiApplication.platformName() in _NO_GL_PLATFORMS:
        return False
    try:
        import pyqtgraph.opengl  # noqa: F401 - needs PyOpenGL, an optional dependency
    except Exception:            # noqa: BLE001 - ImportError, or PyOpenGL failing to find a GL library
        return False
    context = QOpenGLContext()
    if not context.create():
        return False
    surface = QOffscreenSurface()
    surface.setFormat(context.format())
    surface.create()
    if not (surface.isValid() and context.makeCurrent(surface)):
        return False
    context.doneCurrent()
    return True


def make_node_view(parent=None) -> NodeView3D | ThreeViewPlot:
    """The 3D view when OpenGL works here, else the three 2D projections; never raises for lack of OpenGL."""
    if opengl_available():
        try:
            return NodeView3D(parent)
        except Exception:        # noqa: BLE001 - a broken GL stack must cost the 3D view, not the app
            pass
    return ThreeViewPlot(parent)
