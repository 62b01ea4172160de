"""What the node views show: the scene (two node sets, their pairs, their error ellipsoids), its legend and label font.

Why apart: the 3D view (:mod:`snreg_gui.common.node_view_3d`) and the three 2D projections
(:mod:`snreg_gui.common.three_view`) show the same :class:`NodeScene` the same way; this is what they share.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from PySide6.QtGui import QFont

from snreg.nodes import NodeSet
from snreg.registration.naming import shown_preop_ids
from snreg.registration.report import INTRAOP_COLOUR, PAIR_COLOUR, PREOP_COLOUR

__all__ = ["NodeScene", "legend_html", "label_font", "xyz_of", "MISSING_COLOUR", "ELLIPSE_ALPHA", "LANDMARK_COLOUR",
           "SUSPECT_COLOUR", "PREOP_MAPPED", "PREOP_UNREGISTERED", "PREOP_OUT_OF_DATE", "DrawnWhenShown"]

MISSING_COLOUR = "#ff7f0e"          # a preop node with no intraop partner yet (not found, or not removed yet)
LANDMARK_COLOUR = "#2ca02c"         # anatomical landmarks, both sides (CT: hollow diamond, touched: filled)
SUSPECT_COLOUR = "#9400d3"          # a landmark the registration left out as contradicting the rest
ELLIPSE_ALPHA = 0.45                # each node's 90 % ellipsoid is drawn in its node's colour, this opaque (0-1)
# What the preop markers are, as the legend names them: the scene says which, so the legend never claims a mapping
# the drawing does not show (an out-of-date result's pairs are not drawn over nodes placed otherwise).
PREOP_MAPPED = "preop (mapped)"
PREOP_UNREGISTERED = "preop, initial alignment (not registered yet)"
PREOP_OUT_OF_DATE = "preop, initial alignment (the result is OUT OF DATE: run again)"


@dataclass(frozen=True)
class NodeScene:
    """What a view shows: preop nodes already in the intraop frame, intraop nodes, and the pairing.

    ``pairing`` is one hot spot (preop index) per intraop node (-1: none), as in ``RegistrationResult``; None: no
    pairs yet.
    ``missing`` is one flag per preop node: left unpaired by the registration (drawn apart); None: not known.
    Each set's covariances (``NodeSet.cov``, in the view's frame) are drawn as 90 % error ellipsoids.
    ``preop_landmarks`` (in the intraop frame, as the preop nodes) and ``intraop_landmarks``: anatomical landmarks, ids
    = names, drawn with a marker of their own and named, never as nodes; ``suspects``: the names the registration
    left out as contradicting the rest (named so on the view). ``preop_caption``: what the preop markers are, as the
    legend names them (None: :data:`PREOP_MAPPED` with a pairing, else :data:`PREOP_UNREGISTERED`; the panel says
    :data:`PREOP_OUT_OF_DATE` when a result exists but no longer answers its inputs).
    """

    preop: NodeSet | None = None
    intraop: NodeSet | None = None
    pairing: np.ndarray | None = None
    missing: np.ndarray | None = None
    preop_landmarks: NodeSet | None = None
    intraop_landmarks: NodeSet | None = None
    suspects: tuple = ()
    preop_caption: str | None = None

    def legend(self) -> str:
        """The legend for this scene (:func:`legend_html`): its preop caption, the result's marks only with pairs."""
        result = self.pairing is not None
        caption = self.preop_caption or (PREOP_MAPPED if result else PREOP_UNREGISTERED)
        return legend_html(self.has_landmarks, preop=caption, result=result)

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

    def ellipsoids(self) -> tuple[tuple[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray | None]]:
        """((preop centres, covariances), (intraop centres, covariances)): mm and mm^2 in the view's frame, the
        covariances None where the set carries none (:mod:`snreg_gui.common.ellipses` draws them)."""
        return ((xyz_of(self.preop), None if self.preop is None else self.preop.cov),
                (xyz_of(self.intraop), None if self.intraop is None else self.intraop.cov))

    def texts(self) -> tuple[list[str], list[str]]:
        """(preop, intraop) label texts: the ids, preop ids marked "P:" when they repeat intraop ids."""
        intraop = [] if self.intraop is None else list(self.intraop.ids)
        preop = [] if self.preop is None else shown_preop_ids(self.preop.ids, intraop)
        return preop, intraop


    def landmark_texts(self) -> tuple[list[str], list[str]]:
        """(CT, touched) landmark label texts: the names, a suspect one marked "(suspect)"; a CT landmark also touched
        is named once, at the touched one (the names are long: two of each crowd the view)."""
        touched = set(() if self.intraop_landmarks is None else self.intraop_landmarks.ids)

        def named(marks, skip=frozenset()):
            return [] if marks is None else ["" if n in skip else f"{n} (suspect)" if n in self.suspects else n
                                             for n in marks.ids]
        return named(self.preop_landmarks, touched), named(self.intraop_landmarks)

    def landmark_colours(self) -> tuple[list[str], list[str]]:
        """(CT, touched) label colours: :data:`SUSPECT_COLOUR` for a suspect, else :data:`LANDMARK_COLOUR`."""
        def coloured(marks):
            return [] if marks is None else [SUSPECT_COLOUR if n in self.suspects else LANDMARK_COLOUR
                                             for n in marks.ids]
        return coloured(self.preop_landmarks), coloured(self.intraop_landmarks)

    @property
    def has_landmarks(self) -> bool:
        return any(m is not None and len(m) for m in (self.preop_landmarks, self.intraop_landmarks))


class DrawnWhenShown:
    """What both node views do with a scene given while they are hidden: keep it (``scene_shown``) and draw it when
    next shown, the latest one only.

    Why: the registration tab's view is given a scene after each store and each automatic registration while the
    Acquisition tab is in front; drawing it there (markers, ellipses, labels: pyqtgraph ``setData`` and its layout)
    cost the GUI thread tens of ms per store for a view nobody saw (issue 36). The view never shows a stale scene:
    its ``showEvent`` draws the scene given last before the view is painted. ``scenes_drawn`` counts the draws;
    ``stale`` says a scene waits. A view class defines ``_draw_scene(scene)`` and lists this first among its bases.
    """

    scenes_drawn = 0
    stale = False

    def show_scene(self, scene: NodeScene) -> None:
        """Show ``scene``: drawn now when the view is visible, else when it is next shown."""
        self.scene_shown = scene
        self.stale = True
        if self.isVisible():
            self.draw_scene_now()

    def draw_scene_now(self) -> None:
        """Draw the scene given last if it waits."""
        if self.stale:
            self.stale = False
            self.scenes_drawn += 1
            self._draw_scene(self.scene_shown)

    def showEvent(self, event) -> None:                          # noqa: N802 (Qt's name)
        super().showEvent(event)
        self.draw_scene_now()


def xyz_of(nodes: NodeSet | None) -> np.ndarray:
    """The set's positions (N, 3) mm; none for no set."""
    return np.zeros((0, 3)) if nodes is None else nodes.xyz


def legend_html(landmarks: bool = False, *, preop: str = PREOP_MAPPED, result: bool = True) -> str:
    """One line naming what each mark means, in the marks' colours (both views show it above the nodes): ``preop``
    names the preop markers; "not found yet" and "paired" only with a ``result`` drawn; the landmarks' marks only when
    there are landmarks."""
    marks = (f" &nbsp; <span style='color:{LANDMARK_COLOUR}'>&#9671; landmark (CT) &#9670; landmark (touched)</span>"
             if landmarks else "")
    found = (f"<span style='color:{MISSING_COLOUR}'>&#9675; preop, not found yet</span> &nbsp; " if result else "")
    paired = f"<span style='color:{PAIR_COLOUR}'>&#8212; paired</span> &nbsp; " if result else ""
    return (f"<span style='color:{PREOP_COLOUR}'>&#9675; {preop}</span> &nbsp; {found}"
            f"<span style='color:{INTRAOP_COLOUR}'>&#10005; intraop (stored)</span> &nbsp; {paired}"
            f"<span style='color:{PAIR_COLOUR}'>&#9711; 90 % error of each node, in its colour</span>" + marks)


def label_font() -> QFont:
    """The node labels' font: the application's, at least 9 pt."""
    font = QFont()
    font.setPointSizeF(max(font.pointSizeF(), 9.0))
    return font


