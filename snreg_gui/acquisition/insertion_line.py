"""The acquisition screen's line on the camera's insertion, beside the IMU angles (issue 27).

Why: the IMU shows every turn of the camera, not a slide through the trocar; this line shows the slide as the core
says it ("camera 171.0 mm, +13.0 mm since calibration, tracked"), LOST in bold red when the video cannot follow it
(as STALE is for a stream: every pair is then mapped at the insertion last tracked, and Store SN may be refused),
and, below it in orange, what a large pivot residual means (a trocar that moved, an IMU that is off); the lines of
that warning are reserved, so it appears without moving the plot or the angles. Without tracking it says why
(switched off, or a rig whose camera does not slide).
"""

from __future__ import annotations

from snreg.workflow.acquisition import FrameOutcome
from snreg.workflow.insertion import residual_text
from snreg_gui.acquisition.status import BAD, QUIET, WARN, StatusLine, set_style

TEXT_SCALE = 1.2          # a little larger than the status lines: read from a step away, as the angles are
# the longest it says (a tracked insertion and the pivot warning below it): its lines are kept free, so the warning
# appears without moving the plot or the angles beside it
LONGEST = ("camera 999.9 mm, +99.9 mm since calibration, tracked\nthe camera is 99.9 mm off the pivot model: the "
           "trocar moved or the IMU is off; check both, and calibrate the trocar again if one moved")


class InsertionLine(StatusLine):
    """The insertion of the newest pair, in words, its state as the line's colour; the whole text in the tooltip.
    ``untracked``: what it says when the insertion is not tracked, and why."""

    def __init__(self, untracked: str = "camera insertion not tracked"):
        super().__init__("", 1, min_width=240, reserve=LONGEST)
        font = self.font()
        font.setPointSizeF(font.pointSizeF() * TEXT_SCALE)
        self.setFont(font)
        self._set_lines(self.lines)
        self.untracked = untracked
        self.state = ""          # "tracked", "lost" or "" (not tracked)

    def show_outcome(self, outcome: FrameOutcome) -> None:
        step = outcome.insertion
        if step is None:
            self.state = ""
            self.setText(self.untracked)
            set_style(self, QUIET)
            return
        self.state, residual = step.estimate.state, residual_text(step, outcome.imu_gap_s)
        self.setText(f"{outcome.insertion_text}\n{residual}" if residual else outcome.insertion_text)
        set_style(self, BAD if step.held else WARN if residual else "")
