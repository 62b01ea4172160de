"""The node view without OpenGL: three 2D projections of the trocar frame, as :class:`ThreeViewPlot`.

Why: pyqtgraph's OpenGL view needs PyOpenGL and a working OpenGL context, which remote desktops, virtual machines and
offscreen test runs often lack; this view shows the same :class:`~snreg_gui.common.node_scene.NodeScene` with plain
2D plots (items made once, then ``setData``). A scene given while the view is hidden (the registration tab behind the
acquisition tab, given a scene after each store and each automatic registration) is drawn only when the view is next
shown (:class:`~snreg_gui.common.node_scene.DrawnWhenShown`, issue 36). Its labels (their texts, then their places,
each against every other in pixels: most of a redraw's cost) are placed again after every change of a projection's
range or size while the view is visible; one that changes while it is hidden waits for it to be shown.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QPointF, Qt

from snreg.registration.report import INTRAOP_COLOUR, PAIR_COLOUR, PREOP_COLOUR, VIEWS
from snreg_gui.common.ellipses import ellipse_shadows
from snreg_gui.common.label_layout import place_labels
from snreg_gui.common.node_scene import (ELLIPSE_ALPHA, LANDMARK_COLOUR, MISSING_COLOUR, DrawnWhenShown, NodeScene,
                                        label_font, xyz_of)

LEGEND_MIN_PX = 200         # the legend's narrowest wrapping width
LEGEND_MARGIN_PX = 20       # beside it, each side


__all__ = ["ThreeViewPlot"]


def _faint(colour: str) -> pg.QtGui.QPen:
    """A thin pen in ``colour`` at :data:`ELLIPSE_ALPHA`: an ellipse under the markers, never over them in weight."""
    faint = pg.mkColor(colour)
    faint.setAlphaF(ELLIPSE_ALPHA)
    return pg.mkPen(faint, width=1)


class ThreeViewPlot(DrawnWhenShown, pg.GraphicsLayoutWidget):
    """Three projections of the trocar frame (along z: x-y, along y: x-z, along x: y-z): preop as blue rings (orange
    when not found yet), intraop as red crosses, landmarks as green diamonds (hollow: CT, filled: touched), each node's
    90 % error ellipsoid as its shadow (faint, in the node's colour), a legend above; labels beside their markers,
    moved apart so none covers another."""

    kind = "three-view"

    def __init__(self, parent=None):
        super().__init__(parent)
        self.setBackground("w")
        self.scene_shown = NodeScene()
        self.legend = self.addLabel(self.scene_shown.legend(), row=0, col=0, colspan=len(VIEWS))
        self.legend.item.setTextWidth(LEGEND_MIN_PX)    # wrapped to the view's width (resizeEvent): as one line it
        self.legend.updateMin()                          # held the views wider than a 1024x700 window's pane
        self.plots, self.preop_dots, self.missing_dots, self.intraop_dots, self.pair_lines = [], [], [], [], []
        self.landmark_dots: list[tuple[pg.ScatterPlotItem, pg.ScatterPlotItem]] = []    # per projection: CT, touched
        self.ellipses: list[dict[str, pg.PlotDataItem]] = []       # per projection: "preop", "missing", "intraop"
        self._labels: list[tuple[list[pg.TextItem], list[pg.TextItem], list[pg.TextItem]]] = []   # + landmarks
        self._anchors: list[np.ndarray] = []
        self._texts: tuple = ([], [], [], [], [])           # preop texts, their colours, intraop, landmarks, colours
        self.unplaced: set[int] = set()     # projections whose labels wait for the view to be shown
        for column, (name, h, v) in enumerate(VIEWS):
            plot = self.addPlot(row=1, col=column, title=f"{name} ({'xyz'[h]}-{'xyz'[v]})")
            plot.setAspectLocked(True)
            plot.showGrid(x=True, y=True, alpha=0.3)
            plot.setLabel("bottom", f"{'xyz'[h]} (mm)")
            plot.setLabel("left", f"{'xyz'[v]} (mm)")
            self.ellipses.append({side: plot.plot(pen=_faint(colour), connect="finite") for side, colour in
                                  (("preop", PREOP_COLOUR), ("missing", MISSING_COLOUR), ("intraop", INTRAOP_COLOUR))})
            lines = plot.plot(pen=pg.mkPen(PAIR_COLOUR, width=1.5), connect="pairs")
            preop = pg.ScatterPlotItem(symbol="o", size=13, brush=None, pen=pg.mkPen(PREOP_COLOUR, width=2.5))
            missing = pg.ScatterPlotItem(symbol="o", size=13, brush=None,
                                         pen=pg.mkPen(MISSING_COLOUR, width=2.5, style=Qt.PenStyle.DashLine))
            intraop = pg.ScatterPlotItem(symbol="x", size=12, brush=pg.mkBrush(INTRAOP_COLOUR), pen=None)
            marks = (pg.ScatterPlotItem(symbol="d", size=14, brush=None, pen=pg.mkPen(LANDMARK_COLOUR, width=2.5)),
                     pg.ScatterPlotItem(symbol="d", size=9, brush=pg.mkBrush(LANDMARK_COLOUR), pen=None))
            for item in (preop, missing, intraop, *marks):
                plot.addItem(item)
            self.landmark_dots.append(marks)
            self.plots.append(plot)
            self.pair_lines.append(lines)
            self.preop_dots.append(preop)
            self.missing_dots.append(missing)
            self.intraop_dots.append(intraop)
            self._labels.append(([], [], []))
            self._anchors.append(np.zeros((0, 2)))
            plot.vb.sigTransformChanged.connect(lambda _=None, k=column: self._place_labels(k))

    def showEvent(self, event) -> None:                          # noqa: N802 (Qt's name)
        """Draw the scene given while the view was hidden, and place the labels whose projection changed meanwhile."""
        super().showEvent(event)
        self._lay_out_unplaced()

    def resizeEvent(self, event) -> None:                        # noqa: N802 (Qt's name)
        """The legend wrapped to the view's width, so it never holds the three projections past the view's edge."""
        if getattr(self, "legend", None) is not None and not self.closed:   # pyqtgraph resizes before __init__
                                                                          # ends, and on close, its items gone
            self.legend.item.setTextWidth(max(self.width() - 2 * LEGEND_MARGIN_PX, LEGEND_MIN_PX))
            self.legend.updateMin()
        super().resizeEvent(event)

    def _draw_scene(self, scene: NodeScene) -> None:
        """Draw ``scene`` (visible: :class:`~snreg_gui.common.node_scene.DrawnWhenShown` calls it)."""
        self.legend.setText(scene.legend())
        preop, intraop, segments = xyz_of(scene.preop), xyz_of(scene.intraop), scene.pair_segments()
        marks_ct, marks_touched = xyz_of(scene.preop_landmarks), xyz_of(scene.intraop_landmarks)
        mark_texts, mark_colours = sum(scene.landmark_texts(), []), sum(scene.landmark_colours(), [])
        missing = scene.missing_mask()
        preop_texts, intraop_texts = scene.texts()
        (preop_centres, preop_cov), intraop_ellipsoids = scene.ellipsoids()
        shown = {"preop": (preop_centres[~missing], None if preop_cov is None else preop_cov[~missing]),
                 "missing": (preop_centres[missing], None if preop_cov is None else preop_cov[missing]),
                 "intraop": intraop_ellipsoids}
        self._texts = (preop_texts, [MISSING_COLOUR if m else PREOP_COLOUR for m in missing], intraop_texts,
                       mark_texts, mark_colours)
        for k, (_, h, v) in enumerate(VIEWS):
            outlines = [np.zeros((0, 2))]
            for side, (centres, covariances) in shown.items():
                x, y = ellipse_shadows(centres, covariances, h, v)
                self.ellipses[k][side].setData(x=x, y=y, connect="finite")
                outlines.append(np.column_stack([x, y])[np.isfinite(x)])
            self.preop_dots[k].setData(x=preop[~missing, h], y=preop[~missing, v])
            self.missing_dots[k].setData(x=preop[missing, h], y=preop[missing, v])
            self.intraop_dots[k].setData(x=intraop[:, h], y=intraop[:, v])
            self.pair_lines[k].setData(x=segments[:, h], y=segments[:, v], connect="pairs")
            for item, xyz in zip(self.landmark_dots[k], (marks_ct, marks_touched)):
                item.setData(x=xyz[:, h], y=xyz[:, v])
            self._anchors[k] = np.vstack([preop[:, [h, v]], intraop[:, [h, v]], marks_ct[:, [h, v]],
                                          marks_touched[:, [h, v]]])
            self._fit(self.plots[k], np.vstack([self._anchors[k]] + outlines))
            self._lay_out(k)

    def _lay_out(self, k: int) -> None:
        """Projection ``k``'s labels: their texts, then their places."""
        preop_texts, preop_colours, intraop_texts, mark_texts, mark_colours = self._texts
        preop_labels, intraop_labels, mark_labels = self._labels[k]
        self._sync_labels(self.plots[k], preop_labels, preop_texts, preop_colours)
        self._sync_labels(self.plots[k], intraop_labels, intraop_texts, [INTRAOP_COLOUR] * len(intraop_texts))
        self._sync_labels(self.plots[k], mark_labels, mark_texts, mark_colours)
        self._place_labels(k, hidden_too=True)

    def _lay_out_unplaced(self) -> None:
        for k in sorted(self.unplaced):
            self._lay_out(k)

    @staticmethod
    def _fit(plot, points: np.ndarray) -> None:
        """Show every node (and its ellipse) with a margin on each side for the labels."""
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
            item.setFont(label_font())
            plot.addItem(item, ignoreBounds=True)
            pool.append(item)
        while len(pool) > len(texts):
            plot.removeItem(pool.pop())
        for item, text, colour in zip(pool, texts, colours):
            item.setText(text, color=colour)

    def _place_labels(self, k: int, hidden_too: bool = False) -> None:
        """Put projection ``k``'s labels beside their markers (in pixels, none covering another), after every
        change of its range or size; while the view is hidden (unless ``hidden_too``) only note that they wait (laid
        out in full when shown)."""
        if not (hidden_too or self.isVisible()):
            self.unplaced.add(k)
            return
        self.unplaced.discard(k)
        preop_labels, intraop_labels, mark_labels = self._labels[k]
        items = preop_labels + intraop_labels + mark_labels
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
        """The (preop, intraop) label texts drawn in projection ``view`` (laid out now if they waited)."""
        self._lay_out_unplaced()
        preop, intraop, _ = self._labels[view]
        return [item.toPlainText() for item in preop], [item.toPlainText() for item in intraop]

    def landmark_texts(self, view: int = 0) -> list[str]:
        """The landmark label texts drawn in projection ``view`` (CT ones first, then the touched ones; laid out now if
        they waited)."""
        self._lay_out_unplaced()
        return [item.toPlainText() for item in self._labels[view][2]]

    def label_boxes(self, view: int = 0) -> np.ndarray:
        """(N, 4) scene rectangles (left, top, right, bottom, px) of projection ``view``'s labels, preop first, then
        intraop, then landmarks; laid out now if they waited for the view to be shown."""
        self._lay_out_unplaced()
        preop, intraop, marks = self._labels[view]
        rects = [item.sceneBoundingRect() for item in preop + intraop + marks]
        return np.array([[r.left(), r.top(), r.right(), r.bottom()] for r in rects]).reshape(-1, 4)
