"""The headless demo's navigation checked against the truth: per processed frame, each hot spot not found yet as the
acquisition screen would draw it from the registration available then, beside where the phantom really has it.

Why: the surgeon steers by the hot spots drawn on the feeds (:mod:`snreg.workflow.navigation`); only the simulator
knows where they really are and where the camera really is, so the demo records both: the hot spot's predicted
position (the registration's mapping, trocar frame) and its 90 % bound against the phantom node's truth, and its pixel
as drawn (from the estimated camera pose, the function the GUI uses) against the same point from the true pose and the
truth from the true pose (docs/design.md, Command line: ``snreg demo --headless --json`` ``"navigation"``).

>>> log = NavigationLog(preop, hot_spot_truth, estimated_project, true_project, image_size)
>>> log.registered(result)                          # after each store, the registration of the nodes stored so far
>>> log.frame(index, t_s, camera_from_trocar, true_camera_from_trocar, tip_trocar, found=stored_hot_spots)
>>> log.entries                                     # the JSON entries
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from snreg import geometry
from snreg.demo.phantom import hot_spot_of_sources
from snreg.registration import RegistrationResult
from snreg.registration.report import MissingNode
from snreg.workflow.navigation import NavigationState, Project, hot_spot_view, navigation_state

__all__ = ["NavigationLog", "hot_spot_truth"]


def hot_spot_truth(preop_xyz, sources, nodes_trocar) -> dict[int, tuple[int, np.ndarray]]:
    """Preop index -> (phantom node, its true trocar position (3,) mm) for each hot spot: the segmented hot spot
    nearest each phantom source is that node's (the correspondence the demo's pairing is scored by)."""
    nearest = hot_spot_of_sources(preop_xyz, sources)
    return {int(k): (n, np.asarray(nodes_trocar[n], float)) for n, k in enumerate(nearest)}


def _pixel(mark) -> list | None:
    return None if mark.pixel is None else [round(float(v), 2) for v in mark.pixel]


def _mm(xyz) -> list:
    return [round(float(v), 3) for v in xyz]


@dataclass
class NavigationLog:
    """The ``"navigation"`` entries of a run (module docstring). ``truth``: :func:`hot_spot_truth`; ``project`` and
    ``true_project``: the tracker's projection on the calibration acquisition uses and on the true cameras, both of
    ``image_size`` (width, height) px."""

    preop: object
    truth: dict
    project: Project
    true_project: Project
    image_size: tuple[int, int]
    entries: list = field(default_factory=list)
    result: RegistrationResult | None = None
    state: NavigationState = NavigationState()

    def registered(self, result: RegistrationResult | None) -> None:
        """The registration of the nodes stored now: the frames after this one are drawn from it (None: they do not
        register yet, so nothing is drawn or logged)."""
        self.result = result
        self.state = NavigationState() if result is None else navigation_state(self.preop, result)

    def frame(self, index: int, t_s: float, camera_from_trocar: np.ndarray, true_camera_from_trocar: np.ndarray,
              tip_trocar, found_nodes: set[int]) -> None:
        """One processed frame: an entry per hot spot whose phantom node is not in ``found_nodes`` (the phantom nodes
        stored so far), once a registration exists. ``shown``: the registration lists it as not found, so the feeds
        draw it (on screen, or as an arrow at the border)."""
        if self.result is None:
            return
        mapped = geometry.apply(self.result.transform, self.preop.xyz)
        listed = {t.preop_index: t for t in self.state.targets}
        bounds = self.result.target_error_mm
        for k, (node, truth) in sorted(self.truth.items()):
            if node in found_nodes:
                continue
            target = listed.get(k) or _unlisted(self.preop, k, mapped[k], float(bounds[k]))
            drawn = hot_spot_view(target, camera_from_trocar, self.project, self.image_size, tip_trocar)
            true_pose = hot_spot_view(target, true_camera_from_trocar, self.true_project, self.image_size)
            true_spot = hot_spot_view(_unlisted(self.preop, k, truth, 0.0), true_camera_from_trocar, self.true_project,
                                      self.image_size)
            self.entries.append({
                "frame": int(index), "t_s": round(float(t_s), 3), "hot_spot": self.preop.ids[k],
                "shown": k in listed, "confident": self.state.confident, "predicted_trocar": _mm(mapped[k]),
                "bound_mm": round(float(bounds[k]), 3), "truth_trocar": _mm(truth),
                "left_px": _pixel(drawn.eyes[0]), "left_px_true_pose": _pixel(true_pose.eyes[0]),
                "truth_left_px": _pixel(true_spot.eyes[0])})


def _unlisted(preop, k: int, xyz, bound_mm: float):
    """A hot spot as a :class:`~snreg.registration.report.MissingNode` at ``xyz`` (the registration paired it, or the
    truth)."""
    return MissingNode(k, preop.ids[k], preop.labels[k], np.asarray(xyz, float), bound_mm)
