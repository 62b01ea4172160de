"""The registration problem: validated inputs, bounds, prior and label costs, shared by every method."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.spatial.transform import Rotation

from snreg import geometry
from snreg.labels import label_cost
from snreg.registration._covariance import covariances
from snreg.registration._landmarks import Landmarks, landmark_pairs

__all__ = ["Problem", "make_problem", "option_number", "option_count"]


@dataclass(frozen=True)
class Problem:
    """preop (N, 3) already moved by ``initial``; intraop (M, 3); mm throughout.

    ``initial`` is the rough ``intraop_from_preop`` the bounds are measured from; every
    solver returns a correction ``D`` in the initial-aligned frame and the final
    transform is ``D @ initial``. ``label_nats`` (N, M) is the label cost of pairing
    preop n with intraop m in nats (zeros without labels). Covariances, when given, are each node's own error
    (the preop ones turned with the nodes by ``initial``).
    """

    preop: np.ndarray
    intraop: np.ndarray
    initial: np.ndarray
    label_nats: np.ndarray
    max_rotation_deg: float
    max_translation_mm: float
    seed: int
    intraop_cov: np.ndarray | None = None      # (M, 3, 3) mm^2 per intraop node, or None
    preop_cov: np.ndarray | None = None        # (N, 3, 3) mm^2 per preop node, turned by ``initial``, or None
    landmarks: Landmarks | None = None         # landmark pairs (preop ones turned by ``initial``), or None
    vertical: np.ndarray | None = None         # (3,) unit: down in the intraop frame when gravity gave the start
    down_sd_deg: float = 10.0                  # how well the two downs agree (sd of the tilt between them)

    @property
    def anisotropic(self) -> bool:
        """Whether nodes carry their own covariances (:mod:`snreg.registration._covariance`)."""
        return self.intraop_cov is not None or self.preop_cov is not None

    @property
    def n_landmarks(self) -> int:
        return 0 if self.landmarks is None else len(self.landmarks)

    @property
    def weighted(self) -> bool:
        """Whether pairs carry errors of their own (covariances, landmarks): the general model of
        :mod:`snreg.registration._covariance` rather than the isotropic one."""
        return self.anisotropic or self.n_landmarks > 0

    @property
    def min_pairs(self) -> int:
        """Node pairs a candidate needs: three points fix a correction, landmark pairs count."""
        return max(0, 3 - self.n_landmarks)

    @cached_property
    def intraop_eigen(self) -> tuple[np.ndarray, np.ndarray]:
        """The intraop covariances' eigenvalues (M, 3) (zeros without them) and eigenvectors (M, 3, 3): a pair's
        covariance when the hot spots carry none, whatever the correction."""
        if self.intraop_cov is None:
            return np.zeros((len(self.intraop), 3)), np.broadcast_to(np.eye(3), (len(self.intraop), 3, 3))
        eigen, vectors = np.linalg.eigh(self.intraop_cov)
        return np.maximum(eigen, 0.0), vectors

    @property
    def centre(self) -> np.ndarray:
        """The preop centroid (initial-aligned): translations are measured as its displacement."""
        return self.preop.mean(axis=0)

    @property
    def rotation_bound_deg(self) -> float:
        """The bound on the correction's turn: its whole angle, or from a gravity start its tilt alone (the heading
        about the vertical is free), a few of ``down_sd_deg``."""
        if self.vertical is None:
            return self.max_rotation_deg
        return min(self.max_rotation_deg, TILT_BOUND_SD * self.down_sd_deg)

    def correction_size(self, correction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rotation angle in degrees, centroid displacement in mm) of correction(s) (..., 4, 4); from a gravity start
        the angle is the tilt (how far the correction turns the vertical)."""
        correction = np.asarray(correction)
        if self.vertical is None:
            angle = geometry.rotation_angle_deg(correction)
        else:
            turned = np.einsum("...ij,j->...i", correction[..., :3, :3], self.vertical)
            angle = np.degrees(np.arccos(np.clip(turned @ self.vertical, -1.0, 1.0)))
        c = self.centre
        moved_c = np.einsum("...ij,j->...i", correction[..., :3, :3], c) + correction[..., :3, 3]
        return angle, np.linalg.norm(moved_c - c, axis=-1)

    def within_bounds(self, correction: np.ndarray) -> np.ndarray:
        angle, shift = self.correction_size(correction)
        return (angle <= self.rotation_bound_deg + 1e-9) & (shift <= self.max_translation_mm + 1e-9)

    def prior_nats(self, correction: np.ndarray) -> np.ndarray:
        """Negative log prior of a correction: Gaussian in angle and shift with the bounds at 2 sigma.

        The rough alignment is trusted to be right within the bounds (thesis §3.6.2: 60
        degrees and 6 cm); smaller corrections are more likely than larger ones. From a gravity start the heading is
        uniform and the tilt Gaussian with ``down_sd_deg``.
        """
        angle, shift = self.correction_size(correction)
        turn = 0.5 * (angle / self.down_sd_deg) ** 2 if self.vertical is not None else \
            0.5 * (2.0 * angle / self.max_rotation_deg) ** 2
        return turn + 0.5 * (2.0 * shift / self.max_translation_mm) ** 2


TILT_BOUND_SD = 3.0            # from a gravity start, tilts up to this many down_sd_deg are searched

MAX_NODES = 50                 # per node set: the hypothesis search and the confidence grow with N * M * hypotheses
MAX_COORDINATE_MM = 1e5        # 100 m: anything larger is a unit or parsing error, and overflows the fits


def _as_points(name: str, value, minimum: int, landmarks: int = 0) -> np.ndarray:
    try:
        points = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} nodes must be an (n, 3) array of x, y, z in mm") from None
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} nodes must be an (n, 3) array of x, y, z in mm; got shape {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError(f"{name} nodes contain NaN or infinite coordinates; remove or re-measure those nodes")
    if len(points) < minimum:
        if landmarks:
            raise ValueError(f"registration needs at least {minimum} {name} node{'s' if minimum > 1 else ''} beside "
                             f"{landmarks} landmark pair{'s' if landmarks > 1 else ''} (3 points in all, 1 node at "
                             f"least); got {len(points)}")
        raise ValueError(f"registration needs at least {minimum} {name} nodes (or landmarks named on both sides to "
                         f"make 3 points with them); got {len(points)}")
    if len(points) > MAX_NODES:
        raise ValueError(f"registration handles at most {MAX_NODES} {name} nodes (sentinel nodes number a few to a few "
                         f"tens); got {len(points)}: pass the sentinel nodes only")
    if np.abs(points).max() > MAX_COORDINATE_MM:
        raise ValueError(f"{name} node coordinates reach {np.abs(points).max():.3g} mm; positions must be in mm "
                         f"within {MAX_COORDINATE_MM:.0e} mm of the origin: check the units of the node file")
    return points


DEGENERATE_MM = 0.01          # nodes closer than this to one point or one line do not fix a rotation


def _spans_a_plane(name: str, points: np.ndarray, what: str = "nodes") -> None:
    """ValueError naming a degenerate set: all nodes at one point, or all on one line (a rotation about that line
    would fit them equally well, so no registration is determined)."""
    centred = points - points.mean(axis=0)
    singular = np.linalg.svd(centred, compute_uv=False) / np.sqrt(len(points))   # RMS spread along each axis
    if singular[0] < DEGENERATE_MM:
        raise ValueError(f"the {name} {what} coincide (all {len(points)} within {DEGENERATE_MM:g} mm of one point): "
                         f"a registration needs {what} that span a plane; check the positions")
    if singular[1] < DEGENERATE_MM:
        raise ValueError(f"the {name} {what} are collinear (all {len(points)} within {DEGENERATE_MM:g} mm of one "
                         f"line): a registration needs {what} that span a plane; check the positions")


def make_problem(preop, intraop, *, preop_labels=None, intraop_labels=None, initial=None,
                 max_rotation_deg: float = 60.0, max_translation_mm: float = 60.0, seed: int = 0,
                 intraop_cov=None, preop_cov=None, preop_landmarks=None, intraop_landmarks=None,
                 landmark_sd_mm: float = 2.0, down=None, down_sd_deg: float = 10.0) -> Problem:
    """Check the inputs once (docs/design.md, Registration API) and build the shared :class:`Problem`. With ``down``
    and no ``initial`` the start is gravity's: the two downs aligned, the centroids matched, the heading free."""
    downs = gravity_downs(down, down_sd_deg)
    gravity = downs is not None and initial is None
    if gravity:
        initial = _gravity_start(downs, preop, intraop)
    initial = _initial(initial)
    landmarks = landmark_pairs(preop_landmarks, intraop_landmarks, landmark_sd_mm, initial)
    paired = 0 if landmarks is None else len(landmarks)
    preop = _as_points("preop", preop, max(1, 3 - paired), paired)
    intraop = _as_points("intraop", intraop, max(1, 3 - paired), paired)
    if paired:
        preop_original = geometry.apply(geometry.invert(initial), landmarks.preop)
        _spans_a_plane("preop", np.vstack([preop, preop_original]), "nodes and landmarks")
        _spans_a_plane("intraop", np.vstack([intraop, landmarks.intraop]), "nodes and landmarks")
    else:
        _spans_a_plane("preop", preop)
        _spans_a_plane("intraop", intraop)
    for name, labels, n in (("preop", preop_labels, len(preop)), ("intraop", intraop_labels, len(intraop))):
        if labels is not None and len(labels) != n:
            raise ValueError(f"{name}_labels has {len(labels)} labels for {n} {name} nodes")
    if not (0 < max_rotation_deg <= 180 and 0 < max_translation_mm < np.inf):
        raise ValueError(f"max_rotation_deg must lie in (0, 180] and max_translation_mm be positive and finite; got "
                         f"{max_rotation_deg} and {max_translation_mm}")
    intraop_cov = covariances("intraop", intraop_cov, len(intraop))
    preop_cov = covariances("preop", preop_cov, len(preop))
    if preop_cov is not None:
        preop_cov = initial[:3, :3] @ preop_cov @ initial[:3, :3].T
    return Problem(
        preop=geometry.apply(initial, preop),
        intraop=intraop,
        initial=initial,
        label_nats=label_cost(preop_labels, intraop_labels, len(preop), len(intraop)),
        max_rotation_deg=float(max_rotation_deg),
        max_translation_mm=float(max_translation_mm),
        seed=int(seed),
        intraop_cov=intraop_cov,
        preop_cov=preop_cov,
        landmarks=landmarks,
        vertical=downs[1] if gravity else None,
        down_sd_deg=float(down_sd_deg),
    )


def gravity_downs(down, down_sd_deg: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(down in the preop frame, down in the intraop frame), unit (3,) each, from ``down``; None when None;
    ValueError in one sentence for anything else."""
    if down is None:
        return None
    try:
        pair = np.asarray(down, dtype=float)
    except (TypeError, ValueError):
        pair = np.zeros(0)
    if pair.shape != (2, 3):
        raise ValueError("down must be a pair of vectors: (down in the preop frame, down in the intraop frame), 3 "
                         "numbers each")
    if not np.all(np.isfinite(pair)):
        raise ValueError("down contains NaN or infinite values: give two finite vectors pointing down")
    lengths = np.linalg.norm(pair, axis=1)
    if np.any(lengths < 1e-9):
        raise ValueError(f"down's {'preop' if lengths[0] < 1e-9 else 'intraop'} vector is zero: give a vector pointing "
                         "down in that frame")
    try:
        sd = float(down_sd_deg)
    except (TypeError, ValueError):
        sd = float("nan")
    if not (np.isfinite(sd) and 0.0 < sd <= 45.0):
        raise ValueError(f"down_sd_deg must be a number of degrees above 0 and at most 45, got {down_sd_deg!r}")
    return pair[0] / lengths[0], pair[1] / lengths[1]


def _gravity_start(downs: tuple[np.ndarray, np.ndarray], preop, intraop) -> np.ndarray:
    """(4, 4) the start from gravity: the preop down turned onto the intraop down (the least turn), the preop
    centroid onto the intraop centroid."""
    rotation = Rotation.align_vectors(downs[1][None], downs[0][None])[0].as_matrix()
    try:
        pre_centre = np.asarray(preop, dtype=float).reshape(-1, 3).mean(axis=0)
        intra_centre = np.asarray(intraop, dtype=float).reshape(-1, 3).mean(axis=0)
    except (TypeError, ValueError):
        return np.eye(4)                       # the node checks say what is wrong
    if not (np.all(np.isfinite(pre_centre)) and np.all(np.isfinite(intra_centre))):
        return np.eye(4)
    return geometry.make_transform(rotation, intra_centre - rotation @ pre_centre)


def _initial(initial) -> np.ndarray:
    """The rough alignment as a checked (4, 4) rigid transform (the identity when None)."""
    if initial is None:
        initial = np.eye(4)
    initial = np.asarray(initial, dtype=float)
    if initial.shape != (4, 4) or not np.all(np.isfinite(initial)):
        raise ValueError("initial must be a finite 4x4 rigid transform (intraop_from_preop)")
    rot = initial[:3, :3]
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
        raise ValueError("initial must be a rigid transform: its 3x3 part is not a rotation")
    if not np.allclose(initial[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError("initial must be a rigid transform: its last row must be 0 0 0 1")
    if np.abs(initial[:3, 3]).max() > MAX_COORDINATE_MM:
        raise ValueError(f"initial moves the preop nodes by {np.abs(initial[:3, 3]).max():.3g} mm; its translation "
                         "must be in mm and within reach of the intraop nodes")
    return initial


def option_number(method: str, name: str, value, *, low: float = -np.inf, high: float = np.inf,
                  low_open: bool = False, high_open: bool = False) -> float:
    """A solver option as a finite float within [low, high] (an end excluded when ``*_open``); ValueError otherwise."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = float("nan")
    inside = (np.isfinite(number) and (number > low if low_open else number >= low)
              and (number < high if high_open else number <= high))
    if not inside:
        bounds = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"
        raise ValueError(f"{method} option {name} must be a number in {bounds}, not {value!r}")
    return number


def option_count(method: str, name: str, value) -> int:
    """A solver option that counts something: a whole number >= 1; ValueError otherwise."""
    number = option_number(method, name, value, low=1.0)
    if number != int(number):
        raise ValueError(f"{method} option {name} must be a whole number of at least 1, not {value!r}")
    return int(number)
