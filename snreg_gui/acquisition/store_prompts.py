"""What the acquisition screen says about Store SN: the ready line before a press, the questions after one.

Why apart from the screen: the ready line is a plain function of what the screen knows (the core's store check on the
newest pair, the feed's age, paused or storing), testable without a window; the two questions (a store near a stored
node, and a refusal the operator may override: the camera's insertion lost after the camera moved) are boxes whose
safe answer is the default, so that Enter, or a Space meant for Store SN, never stores by accident.
"""

from __future__ import annotations

from dataclasses import dataclass

from PySide6.QtWidgets import QMessageBox, QPushButton, QWidget

from snreg.imu.monitor import STALE_AFTER_S
from snreg.workflow.acquisition import FrameOutcome
from snreg_gui.acquisition.status import BAD, GOOD, PAUSED, WARN

STORE_ANYWAY = "Store anyway"
DO_NOT_STORE = "Don't store"


@dataclass(frozen=True)
class ReadyLine:
    """Whether Store SN can be pressed now, what a press would meet (in the core's words) and the line's style."""

    enabled: bool
    text: str
    style: str = ""


def ready_line(outcome: FrameOutcome | None, needed: int, *, paused: bool = False, pending: bool = False,
               feed_age_s: float = 0.0, stopped: str = "") -> ReadyLine:
    """The button is pressable whenever frames arrive (the core answers every press); the line says what a press
    would meet. ``needed``: fixes per node; ``feed_age_s``: since the newest pair; ``stopped``: why the feed ended."""
    if paused:
        return ReadyLine(False, "paused for calibration", PAUSED)
    if pending:
        return ReadyLine(False, "storing...")
    if outcome is None:
        return ReadyLine(False, "waiting for the first frame")
    if feed_age_s > STALE_AFTER_S:
        return ReadyLine(False, stopped or f"no frames for {feed_age_s:.0f} s: check the cameras", BAD)
    if outcome.valid_fixes < needed:
        return ReadyLine(True, f"not ready: collecting fixes, {outcome.valid_fixes} of {needed}"
                               + ("" if outcome.fix is not None else f" (no valid fix: {outcome.reason})"), WARN)
    check = outcome.store_check
    if check.refusal:
        return ReadyLine(True, f"not ready: {check.refusal}", WARN)
    state = "held still" if outcome.still else "within the limit, not quite still"
    ask = f"; {check.near.id} is {check.near_mm:.1f} mm away: you will be asked" if check.near is not None else ""
    return ReadyLine(True, f"ready: median of the last {needed} fixes, spread {outcome.window_spread_mm:.1f} mm "
                           f"({state}){ask}", GOOD)


def near_node_box(parent: QWidget, question: str, title: str = "Store SN near a stored node") -> QMessageBox:
    """Store near a stored node? (the question names it; a landmark's: replace the stored one of its name?); No is
    the default."""
    box = QMessageBox(QMessageBox.Icon.Question, title, question,
                      QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No, parent)
    box.setDefaultButton(QMessageBox.StandardButton.No)
    return box


def override_box(parent: QWidget, refusal: str, trigger: str,
                 what: str = "Store SN") -> tuple[QMessageBox, QPushButton]:
    """Store although the guard refused (``refusal``, overridable: it says the override goes on record)? The box and
    its "Store anyway" button; "Don't store" is the default. ``what``: "Store SN" or "Store landmark"."""
    box = QMessageBox(QMessageBox.Icon.Warning, f"{what} refused: the camera's insertion is lost",
                      f"Refused ({trigger}): {refusal}.", parent=parent)
    box.setInformativeText("Store anyway only if you know the camera has not slid since it was last tracked: the "
                           "node is then mapped at the insertion tracked last.")
    store_anyway = box.addButton(STORE_ANYWAY, QMessageBox.ButtonRole.AcceptRole)
    box.setDefaultButton(box.addButton(DO_NOT_STORE, QMessageBox.ButtonRole.RejectRole))
    return box, store_anyway
