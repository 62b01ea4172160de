"""Guidance towards the SPECT nodes not found yet: after a registration, where each missing node should be
(trocar frame, mm, with its 90% bound) and, for the one nearest the probe tip, how far and which way.

Why: the surgeon's question during the procedure is "which SPECT nodes have I not removed yet, and where are
they?"; the acquisition screen answers it live from the latest registration, without a window in this module.

>>> targets = missing_nodes(preop, result)           # snreg.registration.report
>>> line = guidance_line(targets, tip_trocar)      # "nearest missing P4: 24 mm +x -y (±15)"
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.registration.report import MissingNode

__all__ = ["Pointer", "point_to_nearest", "guidance_line", "targets_text", "target_circle"]

_AXIS_WORDS = (("+x", "-x"), ("+y", "-y"), ("+z", "-z"))


@dataclass(frozen=True)
class Pointer:
    """The missing node nearest the tip: its distance (mm) from the tip and the unit direction tip -> node (trocar
    frame); ``within_bound`` when the tip is already inside its 90% bound."""

    target: MissingNode
    distance_mm: float
    direction: np.ndarray

    @property
    def within_bound(self) -> bool:
        return bool(self.distance_mm <= self.target.bound_mm)

    def direction_words(self) -> str:
        """The largest components of the direction as axis words, e.g. "+x -z" (trocar frame)."""
        order = np.argsort(-np.abs(self.direction))
        words = [_AXIS_WORDS[k][0 if self.direction[k] >= 0 else 1] for k in order if abs(self.direction[k]) >= 0.35]
        return " ".join(words)


def point_to_nearest(targets: list[MissingNode], tip_trocar) -> Pointer | None:
    """The pointer to the missing node nearest ``tip_trocar`` (3,) mm; None without targets or without a tip."""
    if not targets or tip_trocar is None:
        return None
    tip = np.asarray(tip_trocar, dtype=float)
    offsets = np.array([t.mapped_xyz for t in targets]) - tip
    distances = np.linalg.norm(offsets, axis=1)
    k = int(np.argmin(distances))
    direction = offsets[k] / distances[k] if distances[k] > 0 else np.zeros(3)
    return Pointer(targets[k], float(distances[k]), direction)


def targets_text(targets: list[MissingNode], where: bool = True) -> str:
    """One line per missing node: id, label, its expected error (the registration's 90 % bound on how far it really is
    from where it is mapped) and, with ``where``, that position: "P4 OBT R: expected within 6 mm (90 %) of (12, -30,
    85) mm"."""
    if not targets:
        return "every SPECT node is paired"
    return "\n".join(f"{' '.join(filter(None, (t.preop_id, t.preop_label)))}: expected within {t.bound_mm:.0f} mm (90 %)"
                     + (f" of ({t.mapped_xyz[0]:.0f}, {t.mapped_xyz[1]:.0f}, {t.mapped_xyz[2]:.0f}) mm" if where else "")
                     for t in targets)


def guidance_line(targets: list[MissingNode], tip_trocar) -> str:
    """The live line under the list: the nearest missing node's distance and direction from the tip."""
    pointer = point_to_nearest(targets, tip_trocar)
    if pointer is None:
        return "" if not targets else "nearest missing node: no probe fix"
    t = pointer.target
    where = "inside its bound" if pointer.within_bound else pointer.direction_words()
    return f"nearest missing {t.preop_id}: {pointer.distance_mm:.0f} mm {where} (\u00b1{t.bound_mm:.0f})"


def target_circle(target: MissingNode, camera_from_trocar: np.ndarray, project) -> tuple[np.ndarray, float] | None:
    """Where to draw a missing node on a camera image: the centre (2,) in pixels and a radius in pixels that shows its
    90% bound at its depth; None when it lies behind the camera. ``project`` maps camera points (N, 3) mm to pixels
    (N, 2) (e.g. the tracker's projection for one eye)."""
    centre = camera_from_trocar[:3, :3] @ np.asarray(target.mapped_xyz, float) + camera_from_trocar[:3, 3]
    if centre[2] <= 1.0:
        return None
    across = np.cross(centre, [0.0, 1.0, 0.0])                  # perpendicular to the line of sight
    if np.linalg.norm(across) < 1e-9:
        across = np.array([1.0, 0.0, 0.0])
    edge = centre + target.bound_mm * across / np.linalg.norm(across)
    pixels = np.asarray(project(np.array([centre, edge])), float).reshape(2, 2)
    return pixels[0], float(np.linalg.norm(pixels[1] - pixels[0]))
