"""Navigation to the SPECT hot spots not found yet, on the endoscope's own images: where each one is in each eye
(pixels, its 90 % region as an ellipse, an arrow at the image's edge when it is off screen), how much deeper or
nearer than the probe tip it lies, and the way from the tip in the words of the view ("P4: 47 mm, up and left on
screen, 12 mm deeper").

Why: the surgeon's question is "where are the hot spots I have not found yet?", and the surgeon looks at the
endoscope's image, not at the trocar's axes. The registration maps each hot spot into the trocar frame
(:func:`snreg.registration.report.missing_nodes`); the camera's pose at a frame (the chain at the IMU's orientation
and the camera's insertion: :func:`trocar_from_camera_at`) and the stereo calibration's projection carry it onto both images.
The 90 % region is the sphere of radius ``bound_mm`` about the mapped position (the registration reports no
covariance per hot spot); its image is taken through the projection's Jacobian at the centre, the linear image of
that sphere.

>>> views = navigate(missing, camera_from_trocar, tracker.project, calibration.image_size, tip_trocar)
>>> views[0].eyes[0].pixel, views[0].eyes[0].ellipse, views[0].eyes[0].arrow, views[0].deeper_mm
>>> nearest_words(views)          # "P4: 47 mm, up and left on screen, 12 mm deeper"
>>> state = navigation_state(preop, result)    # the targets, the hot spots found, confident or not
>>> state.banner()               # "pairing not confident: store another node", or "" 
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from snreg import geometry
from snreg.chain import ChainCalibration, trocar_from_camera
from snreg.registration import CONFIDENT
from snreg.registration.report import MissingNode, missing_nodes

__all__ = ["Ellipse", "EdgeArrow", "EyeMark", "HotSpotView", "trocar_from_camera_at", "navigate", "hot_spot_view",
           "region_ellipse", "edge_arrow", "view_words", "nearest_words", "NavigationState", "navigation_state",
           "NEAR_PLANE_MM", "EDGE_MARGIN_FRACTION", "NOT_CONFIDENT", "UPDATING"]

NEAR_PLANE_MM = 1.0            # a point this close to the camera's plane, or behind it, is not on the image
EDGE_MARGIN_FRACTION = 0.04    # an edge arrow sits this fraction of the image's smaller side inside its border
_WORD_SHARE = 0.35             # a direction on screen is named when it carries this share of the way from the tip
_DEPTH_WORD_MM = 1.0           # "deeper"/"nearer" is said from this difference in depth
NOT_CONFIDENT = "pairing not confident: store another node"
UPDATING = "updating: registering the nodes stored now"

Project = Callable[[np.ndarray, int], np.ndarray]     # (N, 3) camera mm, eye (0 left, 1 right) -> (N, 2) pixels


@dataclass(frozen=True)
class Ellipse:
    """A 90 % region on an image: ``centre`` (2,) px, semi-axes ``axes`` (2,) px (major first) and the major axis'
    angle from the image's x axis (degrees, towards +y, i.e. clockwise on screen)."""

    centre: np.ndarray
    axes: np.ndarray
    angle_deg: float


@dataclass(frozen=True)
class EdgeArrow:
    """Where an off-screen hot spot lies: ``position`` (2,) px just inside the image's border and the unit
    ``direction`` (2,) (image x right, y down) it points in, from the image's centre towards the hot spot."""

    position: np.ndarray
    direction: np.ndarray


@dataclass(frozen=True)
class EyeMark:
    """One hot spot on one eye's image: ``pixel`` (2,) and its region's ``ellipse`` when on screen (None off screen
    or behind the camera), else the ``arrow`` at the border."""

    pixel: np.ndarray | None
    ellipse: Ellipse | None
    arrow: EdgeArrow | None

    @property
    def on_screen(self) -> bool:
        return self.pixel is not None


@dataclass(frozen=True)
class HotSpotView:
    """A hot spot not found yet as the endoscope sees it: the ``target``, its position in the camera frame (mm),
    its marks in the left and right images (``eyes``), and relative to the probe tip (None without a fix): the
    distance (mm), how much deeper it lies along the line of sight (``deeper_mm``, camera z; negative: nearer) and
    the way from the tip in the camera frame (``offset_camera`` (3,) mm)."""

    target: MissingNode
    camera_xyz: np.ndarray
    eyes: tuple[EyeMark, EyeMark]
    distance_mm: float | None = None
    deeper_mm: float | None = None
    offset_camera: np.ndarray | None = None

    @property
    def inside(self) -> bool:
        """The tip is within the hot spot's 90 % region."""
        return self.distance_mm is not None and bool(self.distance_mm <= self.target.bound_mm)

    def depth_words(self) -> str:
        """"12 mm deeper" / "5 mm nearer" than the tip, "at the tip's depth" within a millimetre; "" without a tip."""
        if self.deeper_mm is None:
            return ""
        if abs(self.deeper_mm) < _DEPTH_WORD_MM:
            return "at the tip's depth"
        return f"{abs(self.deeper_mm):.0f} mm {'deeper' if self.deeper_mm > 0 else 'nearer'}"


def trocar_from_camera_at(chain: ChainCalibration, earth_from_imu, step=None) -> np.ndarray:
    """(4, 4) ``trocar_from_camera`` at a frame as acquisition maps it: the chain at the camera's insertion of that
    frame (``step``, an :class:`~snreg.workflow.insertion.InsertionStep`; None: the chain's own distance) at the IMU's
    orientation ``earth_from_imu`` (3, 3)."""
    return trocar_from_camera(chain if step is None else step.chain, earth_from_imu)


def navigate(targets: list[MissingNode], camera_from_trocar: np.ndarray, project: Project, image_size,
             tip_trocar=None) -> list[HotSpotView]:
    """:func:`hot_spot_view` of each target, in their order."""
    return [hot_spot_view(t, camera_from_trocar, project, image_size, tip_trocar) for t in targets]


def hot_spot_view(target: MissingNode, camera_from_trocar: np.ndarray, project: Project, image_size,
                  tip_trocar=None) -> HotSpotView:
    """``target`` seen from the camera at ``camera_from_trocar`` (4, 4): its marks in both eyes of ``image_size``
    (width, height) px through ``project`` (e.g. the tracker's), and relative to ``tip_trocar`` (3,) mm (None: no
    fix)."""
    centre = geometry.apply(camera_from_trocar, np.asarray(target.mapped_xyz, float)[None])[0]
    eyes = tuple(_eye_mark(centre, target.bound_mm, project, eye, image_size) for eye in (0, 1))
    if tip_trocar is None:
        return HotSpotView(target, centre, eyes)
    tip = geometry.apply(camera_from_trocar, np.asarray(tip_trocar, float)[None])[0]
    offset = centre - tip
    return HotSpotView(target, centre, eyes, float(np.linalg.norm(offset)), float(offset[2]), offset)


def _eye_mark(centre: np.ndarray, radius_mm: float, project: Project, eye: int, image_size) -> EyeMark:
    """The mark of a camera point ``centre`` (3,) mm in one eye (see :class:`EyeMark`)."""
    width, height = image_size
    if centre[2] > NEAR_PLANE_MM:
        pixel = np.asarray(project(centre[None], eye), float).reshape(2)
        if 0 <= pixel[0] < width and 0 <= pixel[1] < height:
            return EyeMark(pixel, region_ellipse(centre, radius_mm, project, eye), None)
        way = pixel - np.array([width, height]) / 2.0
    else:                                 # behind the camera: the way it lies across the line of sight
        way = centre[:2].copy()
    return EyeMark(None, None, edge_arrow(way, image_size))


def region_ellipse(centre: np.ndarray, radius_mm: float, project: Project, eye: int) -> Ellipse:
    """The image of the sphere of ``radius_mm`` about the camera point ``centre`` (3,) mm in front of the camera:
    through the projection's Jacobian J (2, 3) at the centre (central differences), the ellipse
    ``{c + J u : |u| <= r}``, whose semi-axes are r times the singular values of J."""
    step = 1e-3 * max(float(centre[2]), 1.0)
    probes = centre + np.concatenate([np.eye(3), -np.eye(3)]) * step
    pixels = np.asarray(project(np.vstack([centre, probes]), eye), float).reshape(-1, 2)
    jacobian = (pixels[1:4] - pixels[4:7]).T / (2 * step)
    left, singular, _ = np.linalg.svd(jacobian)
    radius = float(radius_mm) if np.isfinite(radius_mm) else 0.0
    angle = float(np.degrees(np.arctan2(left[1, 0], left[0, 0])))
    return Ellipse(pixels[0], radius * singular[:2], angle)


def edge_arrow(way: np.ndarray, image_size) -> EdgeArrow:
    """The arrow for a hot spot off screen the ``way`` (2,) px from the image's centre (image x right, y down): on
    the line from the centre that way, where it meets the border shrunk by :data:`EDGE_MARGIN_FRACTION`."""
    width, height = (float(v) for v in image_size)
    way = np.asarray(way, float)
    norm = float(np.linalg.norm(way))
    direction = way / norm if norm > 0 else np.array([0.0, -1.0])
    margin = EDGE_MARGIN_FRACTION * min(width, height)
    half = np.array([width / 2 - margin, height / 2 - margin])
    reach = min(half[k] / abs(direction[k]) for k in (0, 1) if abs(direction[k]) > 1e-12)
    return EdgeArrow(np.array([width, height]) / 2 + reach * direction, direction)


def view_words(view: HotSpotView) -> str:
    """The way from the tip to the hot spot in the view's words: "P4: 47 mm, up and left on screen, 12 mm deeper";
    "the tip is inside P4's 90 % region" once it is; "P4: no probe fix" without a tip. Screen directions are named
    when they carry at least :data:`_WORD_SHARE` of the way (camera frame: x right, y down on screen)."""
    name = view.target.preop_id
    if view.distance_mm is None:
        return f"{name}: no probe fix"
    if view.inside:
        return f"the tip is inside {name}'s 90 % region"
    share = view.offset_camera / max(view.distance_mm, 1e-9)
    screen = [word for value, (plus, minus) in ((share[1], ("down", "up")), (share[0], ("right", "left")))
              if abs(value) >= _WORD_SHARE for word in [plus if value > 0 else minus]]
    parts = [f"{name}: {view.distance_mm:.0f} mm"]
    if screen:
        parts.append(f"{' and '.join(screen)} on screen")
    if view.depth_words():
        parts.append(view.depth_words())
    return ", ".join(parts)


def nearest_words(views: list[HotSpotView]) -> str:
    """:func:`view_words` of the hot spot nearest the tip (the first when there is no tip); "" without any."""
    if not views:
        return ""
    with_tip = [v for v in views if v.distance_mm is not None]
    return view_words(min(with_tip, key=lambda v: v.distance_mm) if with_tip else views[0])


@dataclass(frozen=True)
class NavigationState:
    """What the feeds may show of a registration: the hot spots it left unfound (``targets``), the hot spots paired
    with a stored node (``found``, preop ids), whether every claim of that pairing is confident, and ``stale``: why
    it does not answer the nodes stored now, in words ("" when it does)."""

    targets: tuple[MissingNode, ...] = ()
    found: tuple[str, ...] = ()
    confident: bool = False
    stale: str = ""

    def banner(self) -> str:
        """The line the feeds say over the targets: stale first, then an unconfident pairing; "" when current and
        confident."""
        if self.stale:
            return self.stale
        if self.targets and not self.confident:
            return NOT_CONFIDENT
        return ""

    @property
    def drawn_as_confident(self) -> bool:
        """Whether the targets may be drawn as current and confident (else they are greyed, with the banner)."""
        return not self.stale and self.confident

    def updating(self, why: str = UPDATING) -> "NavigationState":
        """The same targets, said to be out of date (a registration running, nodes stored since)."""
        return replace(self, stale=why)


def navigation_state(preop, result) -> NavigationState:
    """The :class:`NavigationState` of a registration ``result`` of ``preop`` (a NodeSet): its missing hot spots
    (:func:`~snreg.registration.report.missing_nodes`), the hot spots it paired, and its confidence (every claim at
    least :data:`~snreg.registration.CONFIDENT`)."""
    pairing = np.asarray(result.pairing, dtype=int)
    found = tuple(preop.ids[k] for k in sorted(set(pairing[pairing >= 0].tolist())))
    confident = bool(len(result.confidence) and np.all(np.asarray(result.confidence) >= CONFIDENT))
    return NavigationState(tuple(missing_nodes(preop, result)), found, confident)
