"""The hot spots not found yet as the feeds draw them: the core's views (:mod:`snreg.workflow.navigation`) turned
into each feed's layer in display pixels.

Why apart: the acquisition worker computes the views for every frame in its thread (the projection is the tracker's);
this is only the translation into what :class:`~snreg_gui.common.feed_view.FeedView` paints, with the registration's
state said in words on the feed (an unconfident pairing, a registration running or out of date) and its targets
greyed then, never drawn as if confident.
"""

from __future__ import annotations

import numpy as np

from snreg.workflow.navigation import HotSpotView, NavigationState, nearest_words
from snreg_gui.common.feed_view import HotSpotLayer, HotSpotMark


def feed_layer(views: list[HotSpotView], eye: int, state: NavigationState, scale: float) -> HotSpotLayer | None:
    """The layer of ``views`` on eye 0 (left) or 1 (right) at ``scale`` display pixels per camera pixel; None when
    there is nothing to say (no registration)."""
    if not views and not state.found and not state.stale:
        return None
    marks = []
    for view in views:
        mark = view.eyes[eye]
        unknown = "" if np.isfinite(view.target.bound_mm) else "(region unknown)"   # drawn as a point, not as precise
        text = " ".join(filter(None, (view.target.preop_id, view.depth_words(), unknown)))
        if mark.ellipse is not None:
            marks.append(HotSpotMark(text, scale * mark.ellipse.centre, scale * mark.ellipse.axes,
                                     mark.ellipse.angle_deg))
        elif mark.arrow is not None:
            marks.append(HotSpotMark(text, arrow_at=scale * mark.arrow.position, arrow_way=mark.arrow.direction))
    note = f"found: {', '.join(state.found)}" if state.found else ""
    if state.found and not views and not state.stale:
        note += "; every hot spot found"
    return HotSpotLayer(tuple(marks), state.banner(), state.drawn_as_confident, note)


def guidance_text(views: list[HotSpotView], state: NavigationState) -> str:
    """The guidance line under the list: the way to the nearest hot spot in the view's words when the registration is
    current and confident, else what keeps it from being so."""
    if not views:
        return state.banner() if state.stale else ""
    return nearest_words(views) if state.drawn_as_confident else state.banner()
