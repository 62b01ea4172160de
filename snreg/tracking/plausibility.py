"""Does what was found look like the probe? Stripe spacing, stripe width and band diameter against the model.

Why: green things that are not the probe are common in surgery (round fiducials on a phantom, greenish
reflections, a stained swab at the image border). Colour alone took two fiducials 7.2 mm apart for stripes
10 mm apart. A fix is therefore accepted only when the candidate stripes, measured in 3D, agree with the
probe model (:class:`~snreg.probe.ProbeModel`, docs/design.md, Contracts) within stated tolerances:

- spacing: the distance between consecutive triangulated stripe centres (on the axis) against the model's,
  within ``spacing_mm`` plus the triangulation's own depth uncertainty there (a stripe centroid's disparity
  is good to about ``disparity_px``; depth error grows as z^2 / (f b));
- band diameter: the stripes' extent across the image axis against the projected width of a cylinder of the
  model's diameter at their measured depth, within ``diameter`` (relative);
- stripe width: no stripe may extend along the axis more than ``stripe_width`` (relative) beyond what a band of
  the model's width projects to (a disc larger than the band, or two blobs merged, does);
- depth: every stripe within the working depth range.

The monocular ``width`` method cannot triangulate, so :func:`check_flat_bands` asks only that each stripe
be a band, not a disc: its extent along the image axis at most ``band_roundness`` times its extent
across (a 4 mm band on a 10 mm probe seen side-on: 0.4; tilted 60 degrees towards the camera: 0.85; a
round fiducial: 1).

Every measure uses the camera model, so the tolerances mean the same at any resolution and distance.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from snreg.errors import TrackingError
from snreg.probe import ProbeModel
from snreg.tracking.markers import Stripes

__all__ = ["ProbeTolerances", "ProbeShape", "measure_shape", "check_shape", "check_flat_bands"]

_RING_ANGLES = np.linspace(0.0, 2.0 * np.pi, 24, endpoint=False)


@dataclass(frozen=True)
class ProbeTolerances:
    """How far a candidate may differ from the probe model and still be the probe."""

    spacing_mm: float = 2.0          # |stripe spacing - model| beyond the triangulation's depth uncertainty, mm
    disparity_px: float = 0.15       # disparity uncertainty of a stripe centroid (1 sigma) behind that allowance
    diameter: float = 0.3            # |band diameter / model - 1|
    stripe_width: float = 0.6        # a stripe's along-axis extent at most (1 + this) x the model band's
    band_roundness: float = 0.85     # monocular: a stripe's along / across pixel extent at most this


@dataclass(frozen=True)
class ProbeShape:
    """A candidate measured against the model: consecutive spacings (k - 1,) with the model's and the allowance
    (mm), the band diameter (mm) and the stripes' along-axis extents relative to the model's (k,)."""

    spacing_mm: np.ndarray
    model_spacing_mm: np.ndarray
    spacing_allowance_mm: np.ndarray
    diameter_mm: float
    width_ratio: np.ndarray


def measure_shape(points: np.ndarray, s_mm: np.ndarray, stripes: Stripes, probe: ProbeModel,
                  project: Callable[[np.ndarray], np.ndarray], focal_px: float, baseline_mm: float,
                  tolerances: ProbeTolerances) -> ProbeShape:
    """Measure a candidate: ``points`` (k, 3) its triangulated stripe centres on the axis (camera frame, mm),
    ``s_mm`` (k,) the model positions they were assigned, ``stripes`` its left-image blobs, ``project`` the left
    camera's projection of (n, 3) points to (n, 2) pixels."""
    points = np.asarray(points, dtype=float)
    spacing = np.linalg.norm(np.diff(points, axis=0), axis=1)
    model_spacing = np.abs(np.diff(s_mm))
    depth = np.maximum(points[:, 2], 1e-6)
    depth_sigma = depth ** 2 / (focal_px * baseline_mm) * tolerances.disparity_px
    along_axis = np.abs(np.diff(points, axis=0) @ [0.0, 0.0, 1.0]) / np.maximum(spacing, 1e-9)
    allowance = tolerances.spacing_mm + 3.0 * np.hypot(depth_sigma[:-1], depth_sigma[1:]) * along_axis
    axis = points[-1] - points[0]
    axis = axis / np.linalg.norm(axis) if len(points) > 1 and np.linalg.norm(axis) > 0 else np.array([1.0, 0.0, 0.0])
    measured_along, measured_across = _extents(stripes)
    expected_along, expected_across = [], []
    for centre in points:
        surface = _band_surface(centre, axis, probe)
        pixels = project(surface)
        along, across = pixels @ stripes.direction, pixels @ _normal(stripes.direction)
        expected_along.append(np.ptp(along) + 1.0)
        expected_across.append(np.ptp(across) + 1.0)
    diameter = probe.diameter_mm * float(np.median(measured_across / np.array(expected_across)))
    return ProbeShape(spacing, model_spacing, allowance, diameter, measured_along / np.array(expected_along))


def check_shape(shape: ProbeShape, points: np.ndarray, probe: ProbeModel, depth_range_mm: tuple[float, float],
                tolerances: ProbeTolerances) -> None:
    """Raise :class:`TrackingError` saying why, when the measured ``shape`` is not the probe's."""
    near, far = depth_range_mm
    depths = np.asarray(points, dtype=float)[:, 2]
    if depths.min() < near or depths.max() > far:
        raise TrackingError(f"no probe: stripes at {depths.min():.0f}-{depths.max():.0f} mm, outside the working depth "
                            f"range {near:g}-{far:g} mm")
    off = np.abs(shape.spacing_mm - shape.model_spacing_mm) > shape.spacing_allowance_mm
    if off.any():
        k = int(np.argmax(off))
        raise TrackingError(f"no probe: stripes {shape.spacing_mm[k]:.1f} mm apart where the probe's are "
                            f"{shape.model_spacing_mm[k]:g} mm (tolerance {shape.spacing_allowance_mm[k]:.1f} mm)")
    if abs(shape.diameter_mm / probe.diameter_mm - 1.0) > tolerances.diameter:
        raise TrackingError(f"no probe: a band {shape.diameter_mm:.1f} mm across where the probe is "
                            f"{probe.diameter_mm:g} mm (tolerance {100 * tolerances.diameter:.0f}%)")
    if shape.width_ratio.max() > 1.0 + tolerances.stripe_width:
        raise TrackingError(f"no probe: a stripe {shape.width_ratio.max() * probe.stripe_width_mm:.1f} mm long where "
                            f"the probe's are {probe.stripe_width_mm:g} mm (tolerance {100 * tolerances.stripe_width:.0f}%)")


def check_flat_bands(stripes: Stripes, tolerances: ProbeTolerances) -> None:
    """Raise :class:`TrackingError` when a stripe is as long along the image axis as across (a disc, not a band)."""
    along, across = _extents(stripes)
    ratio = along / np.maximum(across, 1.0)
    if ratio.max() > tolerances.band_roundness:
        raise TrackingError(f"no probe: a green mark {ratio.max():.2f} as long as wide, round rather than a band "
                            f"around the probe (at most {tolerances.band_roundness:g})")


def _normal(direction: np.ndarray) -> np.ndarray:
    return np.array([-direction[1], direction[0]])


def _extents(stripes: Stripes) -> tuple[np.ndarray, np.ndarray]:
    """Each stripe's pixel extent (k,) along and across the image axis ``stripes.direction``."""
    ys, xs = np.nonzero(stripes.labels)
    label = stripes.labels[ys, xs]
    pixels = np.column_stack([xs, ys]).astype(float)
    along, across = pixels @ stripes.direction, pixels @ _normal(stripes.direction)
    out_along, out_across = [], []
    for k in range(1, len(stripes) + 1):
        own = label == k
        out_along.append(np.ptp(along[own]) + 1.0 if own.any() else 0.0)
        out_across.append(np.ptp(across[own]) + 1.0 if own.any() else 0.0)
    return np.array(out_along), np.array(out_across)


def _band_surface(centre: np.ndarray, axis: np.ndarray, probe: ProbeModel) -> np.ndarray:
    """(48, 3) points on the two rim circles of a band of the model's width centred at ``centre`` (mm)."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    ring = probe.radius_mm * (np.cos(_RING_ANGLES)[:, None] * e1 + np.sin(_RING_ANGLES)[:, None] * e2)
    half = probe.stripe_width_mm / 2.0
    return np.concatenate([centre + ring - half * axis, centre + ring + half * axis])
