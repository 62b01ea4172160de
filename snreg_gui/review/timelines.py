"""The review screen's timelines: IMU angles, probe tip, the camera's insertion, tracking quality and frame rate on one
linked time axis.

Why: a reviewer reads what was recorded when, and how well, against the moments nodes were stored. An
hour of IMU is 750k points per curve, so every curve is made once, drawn with pyqtgraph's peak
downsampling clipped to the view, and only fed with ``setData``; the IMU angles arrive in blocks while
the fusion runs in a worker (:meth:`TimelinePlots.add_imu_block`). The insertion (issue 27) is drawn where it was
tracked; where it was lost the curve breaks and a red bar shows the insertion those pairs were mapped at (the last
tracked), and each node's insertion is a ring at its store. A stored anatomical landmark has a marker of its own
(green, dotted, labelled with a diamond and its number in the order stored, "\u25c6 2"), never one of the node
markers; :attr:`TimelinePlots.legend`, placed under the plots, names each number ("\u25c6 2 aortic bifurcation"), and
the label's tooltip too. Whole names on the plot overlapped each other and the node labels at 1024x700 and 1366x768,
where the top plot has room for about three label rows (issue 35).

>>> plots = TimelinePlots()
>>> plots.show_review(review)            # a snreg.session.timeline.SessionReview
>>> plots.add_imu_block(euler_block)     # (n, 3) yaw, pitch, roll, in order, until all are in
>>> plots.set_cursor(12.5)               # seconds from the first sample
"""

from __future__ import annotations

import html

import numpy as np
import pyqtgraph as pg
from PySide6.QtWidgets import QLabel

from snreg.session.timeline import SessionReview, gap_after, imu_gap_after, lost_stretches, with_gaps
from snreg_gui.common.node_scene import LANDMARK_COLOUR     # green, as the node views draw landmarks

_XYZ_COLOURS = ("#e6550d", "#31a354", "#3182bd")        # yaw/x, pitch/y, roll/z
_MARKER_PEN = pg.mkPen("#bbbbbb", width=1, style=pg.QtCore.Qt.PenStyle.DashLine)
_CURSOR_PEN = pg.mkPen("#ffd700", width=2)
_GAP_PEN = pg.mkPen("#de2d26", width=6)
_LOST_PEN = pg.mkPen("#de2d26", width=4)
_NODE_RING = "#ffd700"          # a node's insertion, at its store
_LANDMARK_PEN = pg.mkPen(LANDMARK_COLOUR, width=1, style=pg.QtCore.Qt.PenStyle.DotLine)
LANDMARK_LABEL = "\u25c6 "        # a diamond before a landmark's number on its marker and its name in the legend
PROGRESS_POINTS = 20_000       # IMU points per curve drawn while the fusion is still running
LABEL_GAP_PX = 6               # between two labels on one row
LABEL_ROWS = 6                 # at most, however high the top plot


def label_rows(times_s, min_gap_s: float, widths_s=None, max_rows: int = LABEL_ROWS) -> list[int | None]:
    """A row for each label (0 = top), so that labels do not overlap (they did as "SNSNSN4", and a landmark's long
    name ran over the next ones): label k, centred on ``times_s[k]``, is ``widths_s[k]`` wide (default 0) and keeps
    ``min_gap_s`` from its neighbours on its row. Each takes the highest row whose last label ends far enough before
    it, in time order; None when all ``max_rows`` rows are taken there (too crowded to show it whole: its line stays,
    and zooming in gives it room)."""
    times = np.asarray(times_s, dtype=float)
    widths = np.zeros(len(times)) if widths_s is None else np.asarray(widths_s, dtype=float)
    rows: list[int | None] = [None] * len(times)
    ends: list[float] = []                     # where the last label on each row ends
    for k in np.argsort(times, kind="stable"):
        start = times[k] - widths[k] / 2
        row = next((r for r, end in enumerate(ends) if start - end >= min_gap_s), len(ends))
        if row == len(ends):
            if row >= max(max_rows, 1):
                continue
            ends.append(start)
        ends[row] = max(ends[row], times[k] + widths[k] / 2)
        rows[k] = int(row)
    return rows


def label_anchor(t: float, width: float, start: float, end: float) -> float:
    """Where along its width (0 = its left edge, 0.5 its centre) a label ``width`` wide stands on its line at ``t``,
    so that it lies within ``start``..``end``: its centre where it fits, else shifted just inside (a label wider than
    the span starts at ``start``)."""
    if width <= 0:
        return 0.5
    return float(np.clip(np.clip(0.5, 1.0 - (end - t) / width, (t - start) / width), 0.0, 1.0))


def landmark_mark(k: int) -> str:
    """The label of the ``k``-th landmark stored (from 0) on the timeline: "\u25c6 1", "\u25c6 2", ..."""
    return f"{LANDMARK_LABEL}{k + 1}"


def _colour_key() -> str:
    """One line naming the curves' colours (an in-plot legend sat under the node labels)."""
    def names(title: str, words) -> str:
        return f"{title}: " + " ".join(f"<span style='color:{c}'>{w}</span>" for c, w in zip(_XYZ_COLOURS, words))
    insertion = (f"insertion: tracked, <span style='color:#de2d26'>lost (held)</span>, "
                 f"<span style='color:{_NODE_RING}'>&#9675; node</span>")
    return f"{names('IMU', ('yaw', 'pitch', 'roll'))} &nbsp;&nbsp; {names('tip (camera)', 'xyz')} &nbsp;&nbsp; {insertion}"


class TimelinePlots(pg.GraphicsLayoutWidget):
    """Five stacked plots with linked x (seconds from the first sample); node markers and a cursor on each.

    ``node_markers`` maps a node id to its vertical lines (one per plot, labelled on the top plot),
    ``landmark_markers`` a stored landmark's name to its own (green, dotted, "\u25c6 name"). The cursor is
    dragged, or put where a plot is clicked: ``cursor_moved(t_s)`` says where (the review shows the video there);
    :meth:`show_window` shades a node's store window.
    """

    cursor_moved = pg.QtCore.Signal(float)

    def __init__(self):
        super().__init__()
        self.key = self.addLabel(_colour_key(), row=0, col=0)      # above the plots: node labels never cover it
        self.legend = QLabel("")            # the landmarks' numbers and names, word-wrapped; placed by the screen
        self.legend.setWordWrap(True)
        self.legend.hide()
        self.angles = self._plot(0, "IMU (deg)")
        self.tip = self._plot(1, "tip (mm)")                  # short labels: five plots share a 700 px screen
        self.insertion = self._plot(2, "insertion (mm)")
        self.quality = self._plot(3, "quality")
        self.frame_rate = self._plot(4, "frames (1/s)")
        self.frame_rate.setLabel("bottom", "time since the first sample (s)")
        self.plots = (self.angles, self.tip, self.insertion, self.quality, self.frame_rate)
        self.angles.vb.sigResized.connect(self._place_labels)
        self.angles.vb.sigXRangeChanged.connect(self._place_labels)
        for plot in self.plots[1:]:
            plot.setXLink(self.angles)
        self.imu_curves = [self._curve(self.angles, colour, name)
                           for colour, name in zip(_XYZ_COLOURS, ("yaw", "pitch", "roll"))]
        self.tip_curves = [self._curve(self.tip, colour, name) for colour, name in zip(_XYZ_COLOURS, "xyz")]
        self.insertion_curve = self._curve(self.insertion, "#dddddd", "insertion")
        self.lost_curve = self.insertion.plot(pen=_LOST_PEN, connect="pairs", name="lost")
        self.node_insertions = pg.ScatterPlotItem(symbol="o", size=9, pen=pg.mkPen(_NODE_RING, width=2), brush=None)
        self.insertion.addItem(self.node_insertions)
        self.untracked_note = pg.TextItem("", color="#bbbbbb")     # in the plot's own pixels: stays top left
        self.untracked_note.setParentItem(self.insertion.vb)
        self.quality_curve = self._curve(self.quality, "#dddddd", None)
        self.rate_curve = self.frame_rate.plot(pen=pg.mkPen("#dddddd", width=1), stepMode="center", name="frames per s")
        self.gap_curve = self.frame_rate.plot(pen=_GAP_PEN, connect="pairs", name="gaps")
        self.cursors = [pg.InfiniteLine(angle=90, pen=_CURSOR_PEN, movable=True) for _ in self.plots]
        for plot, cursor in zip(self.plots, self.cursors):
            plot.addItem(cursor, ignoreBounds=True)
            cursor.hide()
            cursor.sigDragged.connect(lambda line: self._dragged(line.value()))
        self.windows = [pg.LinearRegionItem(movable=False, brush=(255, 215, 0, 40), pen=pg.mkPen(None))
                        for _ in self.plots]
        for plot, window in zip(self.plots, self.windows):
            plot.addItem(window, ignoreBounds=True)
            window.hide()
        self.scene().sigMouseClicked.connect(self._clicked)
        self.node_markers: dict[str, list[pg.InfiniteLine]] = {}
        self.landmark_markers: dict[str, list[pg.InfiniteLine]] = {}
        self._imu_t = np.zeros(0)
        self._imu_rows = np.zeros(0, dtype=int)
        self._euler = np.zeros((0, 3))
        self._imu_filled = 0

    def _plot(self, row: int, label: str) -> pg.PlotItem:
        plot = self.addPlot(row=row + 1, col=0)
        for side in ("left", "bottom"):          # degrees stay degrees: no "(x0.001)" SI scaling of the axis
            plot.getAxis(side).enableAutoSIPrefix(False)
        plot.setLabel("left", label)
        return plot

    @staticmethod
    def _curve(plot: pg.PlotItem, colour: str, name: str | None) -> pg.PlotDataItem:
        curve = plot.plot(pen=pg.mkPen(colour, width=1), name=name, connect="finite")
        curve.setDownsampling(auto=True, method="peak")
        curve.setClipToView(True)
        return curve

    def clear_review(self) -> None:
        """Empty every curve, remove the node markers, hide the cursor."""
        for curve in (*self.imu_curves, *self.tip_curves, self.insertion_curve, self.lost_curve, self.quality_curve,
                      self.gap_curve, self.node_insertions):
            curve.setData([], [])
        self.untracked_note.setText("")
        self.rate_curve.setData([0.0], [], stepMode="center")
        self._remove_markers()
        self._show_legend([])
        for cursor in self.cursors:
            cursor.hide()
        self.show_window(None)
        self._imu_t, self._euler, self._imu_filled = np.zeros(0), np.zeros((0, 3)), 0
        self._imu_rows = np.zeros(0, dtype=int)

    def show_review(self, review: SessionReview) -> None:
        """Probe, frames and node markers of ``review``; the IMU curves wait for :meth:`add_imu_block`."""
        self.clear_review()
        frames = review.frames
        probe_gaps = gap_after(review.probe.t_s, 1.0 / frames.median_rate_hz if frames.median_rate_hz > 0 else None)
        t_probe, tips = with_gaps(review.probe.t_s, review.probe.tip_mm, probe_gaps)    # gaps drawn as gaps
        for curve, column in zip(self.tip_curves, tips.T):
            curve.setData(t_probe, column)
        self.quality_curve.setData(*with_gaps(review.probe.t_s, review.probe.quality, probe_gaps))
        self._show_insertion(review, 1.0 / frames.median_rate_hz if frames.median_rate_hz > 0 else None)
        self.rate_curve.setData(frames.rate_edges_s, frames.rate_hz, stepMode="center")
        self.gap_curve.setData(np.column_stack([frames.gaps_s[:, 0], frames.gaps_s.sum(axis=1)]).ravel(),
                               np.zeros(2 * len(frames.gaps_s)))
        imu_gaps = imu_gap_after(review.imu)
        self._imu_t, _ = with_gaps(review.imu.t_s, np.zeros(len(review.imu.t_s)), imu_gaps)
        samples = np.arange(len(review.imu.t_s))
        self._imu_rows = samples + np.searchsorted(imu_gaps, samples, side="left")   # each sample's row after the NaNs
        self._euler = np.full((len(self._imu_t), 3), np.nan)
        ends = [t[[0, -1]] for t in (review.imu.t_s, review.probe.t_s, frames.t_s, review.camera.t_s) if len(t)]
        stored = review.stored                             # nodes and landmarks: their labels share the rows
        ends.append(np.array([point.t_s for point in stored]))
        span = np.concatenate(ends)
        width = float(np.ptp(span)) if len(span) else 0.0
        for point in stored:
            if point.is_landmark:
                mark = landmark_mark(len(self.landmark_markers))
                self.landmark_markers[point.id] = self._add_marker(mark, point.t_s, pen=_LANDMARK_PEN,
                                                                   colour=LANDMARK_COLOUR)
                self.landmark_markers[point.id][0].label.setToolTip(f"{mark} {point.id} (anatomical landmark)")
            else:
                self.node_markers[point.id] = self._add_marker(point.id, point.t_s)
        self._show_legend(list(self.landmark_markers))
        if len(span):
            self.angles.setXRange(float(span.min()), float(span.max()), padding=0.02)
        self._place_labels()

    def _show_legend(self, names: list[str]) -> None:
        """The legend under the plots: each landmark's number and name, in the landmark colour; hidden when none."""
        self.legend.setText(" &nbsp; ".join(f"<span style='color:{LANDMARK_COLOUR}'>{landmark_mark(k)}</span> "
                                            f"{html.escape(name)}" for k, name in enumerate(names)))
        self.legend.setVisible(bool(names))

    def marker_labels(self) -> list:
        """The labels of the node and landmark markers (on the top plot)."""
        return [lines[0].label for lines in [*self.node_markers.values(), *self.landmark_markers.values()]]

    def _place_labels(self, *_) -> None:
        """Each marker's label on the highest row where it covers no other (hidden where every row is taken there),
        rows as high as a label from the top of the top plot, and wholly inside the plot (centred on its line, or shifted along it at the plot's ends, where
        half of "SN1" was cut off): measured in pixels, so again whenever the plot is resized or its time range
        changes."""
        labels = self.marker_labels()
        view = self.angles.vb
        (x0, x1), width_px, height_px = view.viewRange()[0], view.width(), view.height()
        if not labels or width_px <= 0 or height_px <= 0 or x1 <= x0:
            return
        s_per_px = (x1 - x0) / width_px
        boxes = [label.boundingRect() for label in labels]          # a TextItem's box is in pixels
        row_px = max(box.height() for box in boxes)
        widths = [box.width() * s_per_px for box in boxes]
        lefts = [label_anchor(label.line.value(), width, x0 + 2 * s_per_px, x1 - 2 * s_per_px)
                 for label, width in zip(labels, widths)]
        rows = label_rows([label.line.value() + (0.5 - left) * width for label, left, width in zip(labels, lefts,
                                                                                                   widths)],
                          LABEL_GAP_PX * s_per_px, widths, min(LABEL_ROWS, max(int(height_px // row_px), 1)))
        for label, row, left in zip(labels, rows, lefts):
            label.setVisible(row is not None)           # crowded: the line alone until zoomed in
            if row is not None:
                label.anchors = [(left, 0), (left, 0)]
                label.setPosition(1.0 - min(row * row_px + 2, height_px) / height_px)

    def _show_insertion(self, review: SessionReview, period_s: float | None) -> None:
        """The insertion where tracked (breaks where lost or not recorded), the lost stretches at the insertion held,
        each node's insertion at its store; a note when the session did not track it."""
        camera = review.camera
        self.insertion_curve.setData(*with_gaps(camera.t_s, camera.trocar_camera_mm, gap_after(camera.t_s, period_s)))
        lost = lost_stretches(camera, review.trocar_camera_mm)
        lost = lost[np.isfinite(lost[:, 2])]                    # held at an unknown distance: the break says it
        self.lost_curve.setData(lost[:, :2].ravel(), np.repeat(lost[:, 2], 2))
        nodes = [(node.t_s, node.trocar_camera_mm) for node in review.nodes if np.isfinite(node.trocar_camera_mm)]
        self.node_insertions.setData(*(np.array(nodes).T if nodes else ([], [])))
        distance = review.trocar_camera_mm
        chain = "the chain's distance" if distance is None else f"the chain's {distance:.1f} mm"
        self.untracked_note.setText("" if len(camera.t_s) else f"not tracked in this session: {chain} throughout")

    def add_imu_block(self, euler_deg: np.ndarray) -> None:
        """The next (n, 3) yaw, pitch, roll values in degrees, in sample order; redraws the IMU curves.

        Until the last block the curves show every k-th sample (at most ``PROGRESS_POINTS``), so a redraw
        while the fusion runs stays cheap however long the session; the last block shows them all.
        """
        end = self._imu_filled + len(euler_deg)
        self._euler[self._imu_rows[self._imu_filled:end]] = euler_deg
        self._imu_filled = end
        last = int(self._imu_rows[end - 1]) + 1 if end else 0
        step = 1 if end == len(self._imu_rows) else max(1, last // PROGRESS_POINTS)
        for curve, column in zip(self.imu_curves, self._euler[:last:step].T):
            curve.setData(self._imu_t[:last:step], column)

    @property
    def imu_shown(self) -> int:
        """How many IMU samples the angle curves show so far."""
        return self._imu_filled

    def set_cursor(self, t_s: float) -> None:
        """Show the cursor at ``t_s`` seconds on every plot."""
        for cursor in self.cursors:
            cursor.setValue(t_s)
            cursor.show()

    def show_window(self, start_s: float | None, end_s: float | None = None) -> None:
        """Shade ``start_s``..``end_s`` (a node's store window) on every plot; None hides it."""
        for window in self.windows:
            window.setVisible(start_s is not None)
            if start_s is not None:
                window.setRegion((start_s, end_s))

    def _dragged(self, t_s: float) -> None:
        self.set_cursor(t_s)
        self.cursor_moved.emit(float(t_s))

    def _clicked(self, event) -> None:
        """A click on a plot puts the cursor there."""
        for plot in self.plots:
            if plot.vb.sceneBoundingRect().contains(event.scenePos()):
                self._dragged(plot.vb.mapSceneToView(event.scenePos()).x())
                return

    def _add_marker(self, text: str, t_s: float, pen=_MARKER_PEN, colour: str = "#dddddd") -> list[pg.InfiniteLine]:
        """A line at ``t_s`` on every plot (dashed grey for a node), labelled ``text`` on the top plot (its row set
        by :meth:`_place_labels`; the text's top at its place)."""
        escaped = text.replace("{", "{{").replace("}", "}}")         # InfiniteLine labels are format strings
        lines = [pg.InfiniteLine(t_s, angle=90, pen=pen, label=escaped if plot is self.angles else None,
                                 labelOpts={"position": 1.0, "color": colour, "fill": (0, 0, 0, 160),
                                            "anchors": [(0.5, 0), (0.5, 0)]})
                 for plot in self.plots]
        for plot, line in zip(self.plots, lines):
            plot.addItem(line, ignoreBounds=True)
        return lines

    def _remove_markers(self) -> None:
        for lines in [*self.node_markers.values(), *self.landmark_markers.values()]:
            for plot, line in zip(self.plots, lines):
                plot.removeItem(line)
        self.node_markers, self.landmark_markers = {}, {}
