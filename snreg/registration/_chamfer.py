"""``chamfer``: chamfer matching of node volumes, as in the thesis (§2.5, §3.6).

Both node sets become 10 mm-diameter filled spheres. The reference (intraop) volume is
turned into its Euclidean distance transform; the template (preop) sphere voxels are
moved by a candidate pose and the distances they hit are averaged (trilinear
interpolation). A compass search over rotation (about the preop centroid) and
translation, bounded to the rotation/translation limits, minimises that mean from the
initial alignment, coarse to fine over a resolution pyramid.

``form="volume"`` is the thesis' voxel method. ``form="exact"`` evaluates the same
template points against the exact distance to the nearest reference sphere,
``max(0, |x - c| - r)``, with no grid (see docs/method/registration.md for the measured equivalence/speed). Landmark pairs add their
distances, weighed against the nodes' by :func:`~snreg.registration._landmarks.landmark_weight`.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial.transform import Rotation

from snreg import geometry
from snreg.registration._landmarks import landmark_weight
from snreg.registration._model import squared_distances
from snreg.registration._problem import Problem, option_number

__all__ = ["solve_chamfer", "NODE_DIAMETER_MM", "DEFAULT_PYRAMID_MM", "DEFAULT_FORM"]

NODE_DIAMETER_MM = 10.0
DEFAULT_PYRAMID_MM = (4.0, 2.0)
DEFAULT_FORM = "exact"


def _ball_offsets(spacing: float, radius: float) -> np.ndarray:
    """Lattice offsets (K, 3) of voxel centres inside a ball (voxels of a filled sphere)."""
    k = int(np.floor(radius / spacing))
    grid = np.mgrid[-k:k + 1, -k:k + 1, -k:k + 1].reshape(3, -1).T * spacing
    return grid[np.linalg.norm(grid, axis=1) <= radius + 1e-9]


class _DistanceVolume:
    """Distance (mm) to the nearest reference sphere, from the EDT of a voxelised volume."""

    def __init__(self, centres: np.ndarray, voxel: float, radius: float):
        margin = radius + 3 * voxel
        self.origin = centres.min(axis=0) - margin
        shape = np.ceil((centres.max(axis=0) + margin - self.origin) / voxel).astype(int) + 1
        self.voxel = voxel
        axes = [self.origin[k] + voxel * np.arange(shape[k]) for k in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        inside = np.zeros(tuple(shape), dtype=bool)
        for c in centres:
            inside |= np.sum((grid - c) ** 2, axis=-1) <= radius**2
        self.distance = ndimage.distance_transform_edt(~inside, sampling=voxel)
        self.upper = self.origin + voxel * (shape - 1)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        clipped = np.clip(points, self.origin, self.upper)
        index = ((clipped - self.origin) / self.voxel).reshape(-1, 3).T
        inside = ndimage.map_coordinates(self.distance, index, order=1, mode="nearest").reshape(points.shape[:-1])
        return inside + np.linalg.norm(points - clipped, axis=-1)


class _ExactDistance:
    """Exact distance (mm) to the nearest reference sphere."""

    def __init__(self, centres: np.ndarray, radius: float):
        self.centres, self.radius = centres, radius
        self.centre_sq = (centres**2).sum(axis=1)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        d2 = (points**2).sum(axis=-1)[..., None] - 2.0 * points @ self.centres.T + self.centre_sq
        return np.maximum(np.sqrt(np.maximum(d2.min(axis=-1), 0.0)) - self.radius, 0.0)


def _corrections(params: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(K, 4, 4) corrections from (K, 6) [rotation vector in degrees about ``centre``, translation mm]."""
    rotation = Rotation.from_rotvec(params[:, :3], degrees=True).as_matrix()
    translation = centre + params[:, 3:] - rotation @ centre
    return geometry.make_transform(rotation, translation)


def _landmark_cost(problem: Problem, correction: np.ndarray):
    """The landmark pairs' part of the chamfer cost, a function of corrections (K, 4, 4): each pair's distance in mm,
    scaled to a node's by the square root of :func:`~snreg.registration._landmarks.landmark_weight` (distances, not
    squares, as the chamfer's are) and shared over the nodes as the mean over the template is; the nodes' variance
    is their nearest-neighbour residual at ``correction`` (the pyramid level's start). Zero without landmarks."""
    if not problem.n_landmarks:
        return lambda corr: 0.0
    marks = problem.landmarks
    nearest = squared_distances(geometry.apply(correction, problem.preop), problem.intraop).min(axis=1)
    scale = np.sqrt(landmark_weight(problem, float(nearest.mean()) / 3.0)) / len(problem.preop)

    def cost(corr: np.ndarray) -> np.ndarray:
        moved = marks.preop @ np.swapaxes(corr[:, :3, :3], 1, 2) + corr[:, None, :3, 3]
        return scale * np.linalg.norm(moved - marks.intraop, axis=-1).sum(axis=1)
    return cost


def solve_chamfer(problem: Problem, *, form: str = DEFAULT_FORM, pyramid_mm=DEFAULT_PYRAMID_MM,
                  diameter_mm: float = NODE_DIAMETER_MM) -> np.ndarray:
    """The correction (4, 4) in the initial-aligned frame."""
    if form not in ("volume", "exact"):
        raise ValueError(f"chamfer form must be 'volume' or 'exact', not {form!r}")
    diameter_mm = option_number("chamfer", "diameter_mm", diameter_mm, low=0.0, low_open=True)
    pyramid_mm = tuple(option_number("chamfer", "pyramid_mm", v, low=0.0, low_open=True)
                       for v in np.atleast_1d(np.asarray(pyramid_mm, dtype=object)))
    radius = diameter_mm / 2.0
    centre = problem.centre
    directions = np.vstack([np.eye(6), -np.eye(6)])
    params = np.zeros(6)
    for voxel in pyramid_mm:
        field = _DistanceVolume(problem.intraop, voxel, radius) if form == "volume" else _ExactDistance(problem.intraop, radius)
        template = (problem.preop[:, None, :] + _ball_offsets(voxel, radius)[None]).reshape(-1, 3)

        marks_cost = _landmark_cost(problem, _corrections(params[None], centre)[0])

        def cost(candidates: np.ndarray) -> np.ndarray:
            corr = _corrections(candidates, centre)
            moved = template @ np.swapaxes(corr[:, :3, :3], 1, 2) + corr[:, None, :3, 3]
            return field(moved).mean(axis=1) + marks_cost(corr)

        best = float(cost(params[None])[0])
        step, min_step = 2.0 * voxel, voxel / 4.0
        while step >= min_step:
            candidates = params + step * directions
            ok = (np.linalg.norm(candidates[:, :3], axis=1) <= problem.max_rotation_deg) & (
                np.linalg.norm(candidates[:, 3:], axis=1) <= problem.max_translation_mm)
            if not ok.any():
                step /= 2.0
                continue
            values = cost(candidates[ok])
            k = int(np.argmin(values))
            if values[k] < best - 1e-9:
                params, best = candidates[ok][k], float(values[k])
            else:
                step /= 2.0
    return _corrections(params[None], centre)[0]
