"""Views of two node sets and their pairs: a 3D OpenGL view, or three 2D projections where OpenGL is missing.

Why: the technician must see at a glance whether the preop nodes (mapped into the intraop frame) sit on the
stored intraop nodes. pyqtgraph's OpenGL view needs PyOpenGL and a working OpenGL context, which remote
desktops, virtual machines and offscreen test runs often lack; :func:`make_node_view` decides at run time and
falls back to :class:`ThreeViewPlot` (axial x-y, coronal x-z, sagittal y-z) rather than ever failing.
Both views take a :class:`NodeScene` through ``show_scene``; items are made once and only updated.

>>> view = make_node_view()            # NodeView3D or ThreeViewPlot; view.kind says which
>>> view.show_scene(NodeScene(mapped_preop_nodes, intraop_nodes, result.pairing))
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import pyqtgraph as pg
from PySide6.QtGui import QGuiApplication, QOffscreenSurface, QOpenGLContext
from PySide6.QtWidgets import QVBoxLayout, QWidget

from snreg.nodes import NodeSet
from snreg.registration.report import INTRAOP_COLOUR, PAIR_COLOUR, PREOP_COLOUR, VIEWS

__all__ = ["NodeScene", "ThreeViewPlot", "NodeView3D", "make_node_view", "opengl_available"]

_NO_GL_PLATFORMS = ("offscreen", "minimal", "vnc")


@dataclass(frozen=True)
class NodeScene:
    """What a view shows: preop nodes already in the intraop frame, intraop nodes, and the pairing.

    ``pairing`` is one preop index per intraop node (-1: extra), as in ``RegistrationResult``; None: no pairs yet.
    """

    preop: NodeSet | None = None
    intraop: NodeSet | None = None
    pairing: np.ndarray | None = None

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


def _xyz(nodes: NodeSet | None) -> np.ndarray:
    return np.zeros((0, 3)) if nodes is None else nodes.xyz


def _texts(nodes: NodeSet | None) -> list[str]:
    return [] if nodes is None else [f"{i} {label}".strip() for i, label in zip(nodes.ids, nodes.labels)]


class ThreeViewPlot(pg.GraphicsLayoutWidget):
    """Axial (x-y), coronal (x-z) and sagittal (y-z) projections: preop as blue rings, intraop as red crosses."""

    kind = "three-view"

    def __init__(self, parent=None):
        super().__init__(parent)
        self.setBackground("w")
        self.scene_shown = NodeScene()
        self.plots, self.preop_dots, self.intraop_dots, self.pair_lines = [], [], [], []
        self._labels: list[tuple[list[pg.TextItem], list[pg.TextItem]]] = []
        for column, (name, h, v) in enumerate(VIEWS):
            plot = self.addPlot(row=0, col=column, title=f"{name} ({'xyz'[h]}-{'xyz'[v]})")
            plot.setAspectLocked(True)
            plot.showGrid(x=True, y=True, alpha=0.3)
            plot.setLabel("bottom", f"{'xyz'[h]} (mm)")
            plot.setLabel("left", f"{'xyz'[v]} (mm)")
            if column == 0:
                plot.addLegend(offset=(5, 5))
            lines = plot.plot(pen=pg.mkPen(PAIR_COLOUR, width=1.5), connect="pairs", name="pairs")
            preop = pg.ScatterPlotItem(symbol="o", size=13, brush=None, pen=pg.mkPen(PREOP_COLOUR, width=2.5),
                                       name="preop (mapped)")
            intraop = pg.ScatterPlotItem(symbol="x", size=12, brush=pg.mkBrush(INTRAOP_COLOUR), pen=None,
                                         name="intraop")
            plot.addItem(preop)
            plot.addItem(intraop)
            self.plots.append(plot)
            self.pair_lines.append(lines)
            self.preop_dots.append(preop)
            self.intraop_dots.append(intraop)
            self._labels.append(([], []))

    def show_scene(self, scene: NodeScene) -> None:
        self.scene_shown = scene
        preop, intraop, segments = _xyz(scene.preop), _xyz(scene.intraop), scene.pair_segments()
        for k, (_, h, v) in enumerate(VIEWS):
            self.preop_dots[k].setData(x=preop[:, h], y=preop[:, v])
            self.intraop_dots[k].setData(x=intraop[:, h], y=intraop[:, v])
            self.pair_lines[k].setData(x=segments[:, h], y=segments[:, v], connect="pairs")
            preop_labels, intraop_labels = self._labels[k]
            self._sync_labels(self.plots[k], preop_labels, preop[:, [h, v]], _texts(scene.preop), PREOP_COLOUR, (0, 1))
            self._sync_labels(self.plots[k], intraop_labels, intraop[:, [h, v]], _texts(scene.intraop),
                              INTRAOP_COLOUR, (0, 0))
            self._fit(self.plots[k], np.vstack([preop, intraop])[:, [h, v]])

    @staticmethod
    def _fit(plot, points: np.ndarray) -> None:
        """Show every node with a margin, wider on the right where the labels are written."""
        if not len(points):
            return
        low, high = points.min(axis=0), points.max(axis=0)
        margin = 0.1 * max(float(np.max(high - low)), 40.0)
        plot.setRange(xRange=(low[0] - margin, high[0] + 4.0 * margin), yRange=(low[1] - margin, high[1] + margin),
                      padding=0)

    @staticmethod
    def _sync_labels(plot, pool: list[pg.TextItem], positions: np.ndarray, texts: list[str], colour, anchor) -> None:
        """Reuse the text items already in ``plot``; add or remove only when the node count changes."""
        while len(pool) < len(texts):
            item = pg.TextItem(color=colour, anchor=anchor)
            plot.addItem(item, ignoreBounds=True)
            pool.append(item)
        while len(pool) > len(texts):
            plot.removeItem(pool.pop())
        for item, text, (x, y) in zip(pool, texts, positions):
            item.setText(text)
            item.setPos(float(x), float(y))

    def label_texts(self, view: int = 0) -> tuple[list[str], list[str]]:
        """The (preop, intraop) label texts drawn in projection ``view``."""
        preop, intraop = self._labels[view]
        return [item.toPlainText() for item in preop], [item.toPlainText() for item in intraop]


class NodeView3D(QWidget):
    """The same scene in a rotatable OpenGL view (pyqtgraph.opengl); build it only when :func:`opengl_available`."""

    kind = "3d"

    def __init__(self, parent=None):
        super().__init__(parent)
        import pyqtgraph.opengl as gl

        self._gl = gl
        self.scene_shown = NodeScene()
        self.view = gl.GLViewWidget()
        self.view.setBackgroundColor("w")
        grid = gl.GLGridItem()
        grid.setSize(400, 400)
        grid.setSpacing(20, 20)
        grid.setColor((0, 0, 0, 40))
        self.view.addItem(grid)
        self.view.addItem(gl.GLAxisItem(size=pg.Vector(50, 50, 50)))
        self.pair_lines = gl.GLLinePlotItem(mode="lines", color=pg.mkColor(PAIR_COLOUR), width=1.5, antialias=True)
        self.preop_dots = gl.GLScatterPlotItem(color=pg.mkColor(PREOP_COLOUR).getRgbF(), size=14, pxMode=True)
        self.intraop_dots = gl.GLScatterPlotItem(color=pg.mkColor(INTRAOP_COLOUR).getRgbF(), size=9, pxMode=True)
        for item in (self.pair_lines, self.preop_dots, self.intraop_dots):
            item.setGLOptions("translucent")
            self.view.addItem(item)
        self._labels: list = []
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.view)

    def show_scene(self, scene: NodeScene) -> None:
        self.scene_shown = scene
        preop, intraop, segments = _xyz(scene.preop), _xyz(scene.intraop), scene.pair_segments()
        self.preop_dots.setData(pos=preop)
        self.intraop_dots.setData(pos=intraop)
        self.pair_lines.setVisible(len(segments) > 0)
        if len(segments):
            self.pair_lines.setData(pos=segments)
        for item in self._labels:
            self.view.removeItem(item)
        self._labels = [self._gl.GLTextItem(pos=p, text=t, color=pg.mkColor(c))
                        for xyz, texts, c in ((preop, _texts(scene.preop), PREOP_COLOUR),
                                              (intraop, _texts(scene.intraop), INTRAOP_COLOUR))
                        for p, t in zip(xyz, texts)]
        for item in self._labels:
            self.view.addItem(item)
        points = np.vstack([preop, intraop])
        if len(points):
            centre = points.mean(axis=0)
            extent = float(np.ptp(points, axis=0).max()) if len(points) > 1 else 100.0
            self.view.setCameraPosition(pos=pg.Vector(*centre), distance=2.5 * max(extent, 50.0))


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
