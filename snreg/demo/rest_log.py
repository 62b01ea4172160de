"""What each rest of the demo's tour gave the store window, so a demo that stored too few nodes says why.

Why: auto-store needs a full window of fixes held still (``STILL_SPREAD_MM``); when a node is never stored, the reason
is in the rests (the window never filled because the live feed skipped frames, or its spread never came under the
limit), not in the frame source, which is closed by the time the demo gives up. :class:`RestLog` keeps, per visit of
the probe to a node, the frames read, the valid fixes and the best (smallest) window spread; :meth:`RestLog.why_missing`
says it in one sentence per node never stored.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["RestLog", "RestVisit"]


@dataclass
class RestVisit:
    """One rest of the probe on ``node``: frames read during it, valid fixes among them, the best spread of a store
    window holding this rest's fixes alone (mm, NaN when the rest gave fewer fixes than the window) and whether a node
    was stored in it."""

    node: int
    frames: int = 0
    fixes: int = 0
    best_spread_mm: float = math.nan
    stored: bool = False


class RestLog:
    """The rests of one run in order (:meth:`add` after each processed frame)."""

    def __init__(self) -> None:
        self.visits: list[RestVisit] = []
        self._resting: int | None = None

    def add(self, node: int | None, outcome, stored: bool = False, window: int = 1) -> None:
        """One processed frame: ``node`` the probe rests on (None while it moves), ``outcome`` the acquisition's
        :class:`~snreg.workflow.acquisition.FrameOutcome`, ``stored`` whether a node was stored at it. A spread counts
        once the rest has given ``window`` valid fixes (the store window holds this rest's fixes alone, none taken
        while the probe moved)."""
        if node is None:
            self._resting = None
            return
        if node != self._resting:
            self.visits.append(RestVisit(node))
            self._resting = node
        visit = self.visits[-1]
        visit.frames += 1
        visit.fixes += outcome.fix is not None
        spread = float(outcome.window_spread_mm) if visit.fixes >= window else math.nan
        if not math.isnan(spread) and not spread >= visit.best_spread_mm:
            visit.best_spread_mm = spread
        visit.stored |= stored

    def why_missing(self, stored_nodes, names, *, fixes_per_node: int, still_mm: float) -> str:
        """One clause per node of ``names`` (index -> name) not in ``stored_nodes``: how often the probe rested on it
        and the best the window did against auto-store's needs; empty when every node was stored."""
        clauses = []
        for node, name in enumerate(names):
            if node in stored_nodes:
                continue
            visits = [v for v in self.visits if v.node == node]
            if not visits:
                clauses.append(f"node {name} was never reached")
                continue
            spreads = [v.best_spread_mm for v in visits if not math.isnan(v.best_spread_mm)]
            rests = f"{len(visits)} rest{'' if len(visits) == 1 else 's'}"
            if not spreads:
                most = max(v.fixes for v in visits)
                frames = max(v.frames for v in visits)
                clauses.append(f"node {name}: the store window never filled on {rests} (at most {most} valid fixes "
                               f"of {fixes_per_node} in {frames} frames processed while resting: the live feed skips "
                               "frames when tracking falls behind; a loaded computer processes too few)")
            else:
                each = ", ".join(f"{s:.2f}" for s in spreads)
                clauses.append(f"node {name}: its best window spread on {rests} was {each} mm; auto-store needs "
                               f"{still_mm:.2f} mm or less")
        return "; ".join(clauses)
