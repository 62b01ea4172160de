"""What Store SN and Store landmark meet before they store: the limits, the verdict in words, and the stored point a
store must ask about first.

Why apart from :mod:`snreg.workflow.acquisition`: the verdict is what the acquisition screen shows on every frame and
asks about, for nodes and landmarks alike; the acquisition decides it (:meth:`~snreg.workflow.acquisition.Acquisition.
check_store`, :meth:`~snreg.workflow.acquisition.Acquisition.check_landmark`), these types say it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.imu.monitor import STALE_AFTER_S
from snreg.landmarks import LANDMARK
from snreg.session import IntraopNode

__all__ = ["StoreLimits", "StoreCheck", "nearest_node", "same_landmark"]


@dataclass(frozen=True)
class StoreLimits:
    """When a manual store is refused or asks first: spread over ``max_spread_mm`` (the app's setting), newest fix
    older than ``fix_stale_s``, an IMU sample farther than ``imu_stale_s`` from a fix's frame; within
    ``duplicate_mm`` of a stored node it asks."""

    max_spread_mm: float = 2.0
    duplicate_mm: float = 5.0
    fix_stale_s: float = 1.0
    imu_stale_s: float = STALE_AFTER_S


@dataclass(frozen=True, eq=False)
class StoreCheck:
    """Whether a store would store now: ``refusal`` (one sentence, "" when it would), ``overridable`` when the
    operator may store anyway (only the insertion's refusal is), and the stored point to ask about first (``near``,
    None when none: for Store SN a node within the duplicate distance, for Store landmark the landmark of the same
    name) and how far it is from here (mm)."""

    refusal: str
    near: IntraopNode | None = None
    near_mm: float = float("nan")
    overridable: bool = False

    @property
    def question(self) -> str:
        """The confirmation to ask when a stored point is near (or has the name), naming it; "" otherwise."""
        if self.near is None:
            return ""
        if self.near.kind == LANDMARK:
            return (f"The landmark {self.near.id!r} is already stored, {self.near_mm:.1f} mm from here. Store it here "
                    "instead (the first stays on record)?")
        label = f" ({self.near.label})" if self.near.label else ""
        return (f"{self.near.id}{label} is already stored {self.near_mm:.1f} mm from here. "
                f"Store this as a new node anyway?")


def nearest_node(nodes: list[IntraopNode], here: np.ndarray, limit_mm: float) -> StoreCheck:
    """No refusal, with the stored node nearest ``here`` (trocar frame, mm) when it lies within ``limit_mm``."""
    if not nodes:
        return StoreCheck("")
    distances = np.linalg.norm(np.array([r.xyz_trocar for r in nodes]) - here, axis=1)
    k = int(np.argmin(distances))
    return StoreCheck("", nodes[k], float(distances[k])) if distances[k] <= limit_mm else StoreCheck("")


def same_landmark(landmarks: list[IntraopNode], name: str, here: np.ndarray) -> StoreCheck:
    """No refusal, with the stored landmark called ``name`` (and its distance from ``here``) when there is one."""
    stored = next((r for r in landmarks if r.id == name), None)
    if stored is None:
        return StoreCheck("")
    return StoreCheck("", stored, float(np.linalg.norm(np.asarray(stored.xyz_trocar) - here)))
