"""Each stored node's own error: a covariance (3x3, mm^2, trocar frame) from the node's geometry and the rig's cited
magnitudes (issue 28).

Why: a stereo fix is not equally uncertain in every direction. At depth Z with baseline b a triangulated point errs
about 2 Z / b times more along its viewing ray than across it (the disparity carries the depth; both eyes average the
lateral position): at 100 mm with the Firefly's 4.3 mm baseline, about 46 times. The probe's tip is extrapolated from
its stripes, so a tilt of the stripe line swings the tip; the count peak puts the node beside the probe's axis and
ahead of its tip; an IMU error turns the node about the pivot by its lever; the trocar-camera distance slides it
along the shaft. Registration that knows each node's shape weighs it accordingly (:mod:`snreg.registration`,
``intraop_cov``; Maier-Hein et al. 2012, Danilchenko and Fitzpatrick 2011).

The parts (first order, independent, summed):

- ``tracking``: each stripe centre triangulated from its two image positions, each off by ``image_sd_px`` per pixel
  coordinate (the inverse of the stacked projections' Jacobian, in the rectified frame where the tracker
  triangulates), carried to the tip through the least-squares line the tracker fits along the stripes; the tracker's
  residual beyond that (``residual_mm`` per axis, isotropic: lighting and segmentation errors of unknown shape, thesis
  Table 4); and the store window's own spread: the median of n fixes with sample covariance S varies as
  ``pi / 2 * S / n`` (the median's efficiency for Gaussian data).
- ``pointing``: the probe's prior. The count peak puts the node's centre within ``pointing_lateral_mm`` of the axis
  (uniform over the disc: ``L^2 / 4`` per lateral axis) and up to ``pointing_axial_mm`` ahead of the tip (uniform:
  ``A^2 / 3`` as a second moment about the tip, so the mean offset ahead is covered, not only its spread).
- ``chain``: the IMU orientation's error turns the node about the pivot, ``s^2 (|p|^2 I - p p^T)`` for a per-axis
  sd s (radians) and the node at p from the pivot; s is ``imu_deg`` once the camera has turned from the reference pose
  by the thesis' smallest tested turn (1 deg; Fig. 19B: 0.26-0.59 deg for turns of 1 to 10 deg, not growing with the
  turn) and in proportion below it (at the reference pose the trocar frame is the IMU's own), with the IMU-camera
  misalignment (``imu_camera_deg``, an angle about an unknown axis: its square over 3 per axis) added. The
  trocar-camera distance's error (``trocar_camera_sd_mm``) and the insertion's change since (``insertion_sd_mm`` while
  it is not tracked; the insertion tracker's own sd once it is) slide the node along the shaft.

Rotating the camera-frame parts into the trocar frame uses the node's own orientation, so each node's ray is its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from snreg.camera import StereoCalibration
from snreg.chain import THESIS_TROCAR_CAMERA_SD_MM, ChainCalibration, reference_rotation, trocar_from_camera
from snreg.probe import ProbeModel

__all__ = ["NodeUncertainty", "node_covariance", "node_covariance_parts", "node_covariance_sources", "summed_covariance",
           "SOURCES", "PART_OF", "triangulation_covariance",
           "tip_covariance", "pointing_covariance", "orientation_covariance", "inside_ellipsoid", "ellipsoid_radius_mm",
           "ELLIPSOID_LEVEL", "ELLIPSOID_SCALE", "SMALLEST_TESTED_TURN_DEG"]

ELLIPSOID_LEVEL = 0.9              # "within x mm (90 %)": the ellipsoid holding 90 % of a node's error
ELLIPSOID_SCALE = float(np.sqrt(chi2.ppf(ELLIPSOID_LEVEL, 3)))   # its semi-axes in sds along them (2.50)
SMALLEST_TESTED_TURN_DEG = 1.0     # thesis Fig. 19B: the IMU's error was measured for turns of 1, 5 and 10 deg
# Each source of a node's error (:func:`node_covariance_sources`) and the part it belongs to (:func:`node_covariance_parts`):
# the stereo image noise along the rays, the tracker's residual, the store window's spread; the probe's pointing; the
# IMU's turn error, the IMU-camera misalignment, the trocar-camera distance and the camera's insertion.
PART_OF = {"image": "tracking", "residual": "tracking", "window": "tracking", "pointing": "pointing", "imu": "chain",
           "imu_camera": "chain", "trocar_camera": "chain", "insertion": "chain"}
SOURCES = tuple(PART_OF)


@dataclass(frozen=True)
class NodeUncertainty:
    """The magnitudes a node's covariance is made of (sd, mm or deg or px); defaults as cited.

    ``image_sd_px``: sd of a stripe centre's position in each image, per pixel coordinate, beyond the frames' own
    jitter (which the window's spread measures): measured on the thesis error model's rendered Firefly frames (sensor
    noise 3, blur 0.92 px) tracked at the phantom's four nodes, 12 of ``snreg budget``'s tracking draws
    (:class:`snreg.simulation.budget_tracking.TrackingBench`): the median fix's error along its covariance's long axis
    is what 0.07 px gives with ``sgbm`` and 0.03 px with ``triangulation``; the thesis gives no pixel figure.
    ``residual_mm``: the tracker's error beyond the image noise, per axis (thesis Table 4, 90-130 mm: step error RMS
    4.0 mm over 40 mm steps, so 4.0 / sqrt(2) per axis). ``pointing_lateral_mm``/``pointing_axial_mm``: the node
    within the probe's 5 mm radius of its axis, and up to 5 mm ahead of the tip (thesis 3.6.1: a 10 mm probe; nodes
    under 10 mm). ``imu_deg``: the IMU's error of a measured turn, per axis (thesis Fig. 19B: 0.4625, sd 0.1167 deg
    for the robot arm's 10 deg turn, so 0.48 deg RMS; 0.6 +- 0.1 deg overall, 5.3.1). ``imu_camera_deg``: the
    IMU-camera misalignment's angle (thesis 4.1: axes aligned by eye, no figure: 0). ``trocar_camera_sd_mm``: the
    trocar-camera distance's error (thesis Table 3: 158 mm, interquartile 157-158 mm, robust sd 0.74 mm).
    ``insertion_sd_mm``: the camera's insertion change per pose while it is not tracked (Table 3's spread over
    orientations, 0.74 mm); a tracked insertion brings its own sd instead.
    """

    image_sd_px: float = 0.07
    residual_mm: float = 2.8
    pointing_lateral_mm: float = 5.0
    pointing_axial_mm: float = 5.0
    imu_deg: float = 0.48
    imu_camera_deg: float = 0.0
    trocar_camera_sd_mm: float = THESIS_TROCAR_CAMERA_SD_MM
    insertion_sd_mm: float = THESIS_TROCAR_CAMERA_SD_MM

    def __post_init__(self):
        for name, value in vars(self).items():
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"the node uncertainty's {name} must be a number of at least 0, not {value}")


def triangulation_covariance(calibration: StereoCalibration, point_camera, image_sd_px: float) -> np.ndarray:
    """(3, 3) mm^2, left camera frame: the first-order covariance of a point triangulated from its images in both
    eyes, each image coordinate off by ``image_sd_px``: ``sd^2 (J^T J)^-1`` with J (4, 3) the stacked rectified
    projections' Jacobian (the tracker triangulates in the rectified frame), rotated back by R1."""
    rectified = np.asarray(calibration.R1, float) @ np.asarray(point_camera, float).reshape(3)
    rows = []
    for P in (np.asarray(calibration.P1, float), np.asarray(calibration.P2, float)):
        h = P[:, :3] @ rectified + P[:, 3]
        if h[2] <= 0:
            raise ValueError(f"the point {np.round(point_camera, 1).tolist()} mm lies behind a camera; a tracked node "
                             "lies in front of both")
        pixel = h[:2] / h[2]
        rows.append((P[:2, :3] - np.outer(pixel, P[2, :3])) / h[2])
    J = np.vstack(rows)
    covariance = image_sd_px**2 * np.linalg.inv(J.T @ J)
    R1 = np.asarray(calibration.R1, float)
    return R1.T @ covariance @ R1


def tip_covariance(calibration: StereoCalibration, probe: ProbeModel, tip_camera, axis_camera,
                   image_sd_px: float) -> np.ndarray:
    """(3, 3) mm^2, camera frame: the tip's covariance when each stripe centre (at ``s_k`` along the axis from the
    tip) is triangulated with :func:`triangulation_covariance` and the tip is extrapolated along the least-squares line
    through them: ``tip = c - s_mean u`` with c the centres' mean and u the fitted direction, so a centre's error
    moves the tip by ``a_k = I / K - s_mean (s_k - s_mean) / sum (s_j - s_mean)^2 (I - u u^T)``."""
    tip, u = np.asarray(tip_camera, float).reshape(3), _unit(axis_camera)
    s = np.asarray(probe.stripe_centres_mm, float)
    offsets = s - s.mean()
    across = np.eye(3) - np.outer(u, u)
    total = np.zeros((3, 3))
    for s_k, offset in zip(s, offsets):
        a = np.eye(3) / len(s) - s.mean() * offset / np.sum(offsets**2) * across
        total += a @ triangulation_covariance(calibration, tip + s_k * u, image_sd_px) @ a.T
    return total


def pointing_covariance(axis_camera, lateral_mm: float, axial_mm: float) -> np.ndarray:
    """(3, 3) mm^2, camera frame: second moments of the node about the probe's tip under the probe's prior: uniform
    within ``lateral_mm`` of the axis (``L^2 / 4`` per lateral axis) and uniform up to ``axial_mm`` ahead of the tip
    (``A^2 / 3``, the mean offset included)."""
    u = _unit(axis_camera)
    along = np.outer(u, u)
    return lateral_mm**2 / 4.0 * (np.eye(3) - along) + axial_mm**2 / 3.0 * along


def orientation_covariance(node_trocar, sd_deg: float) -> np.ndarray:
    """(3, 3) mm^2: the node at ``node_trocar`` (mm from the pivot) turned about the pivot by an orientation error of
    ``sd_deg`` per axis: ``s^2 (|p|^2 I - p p^T)`` (a turn about the lever itself moves nothing)."""
    p = np.asarray(node_trocar, float).reshape(3)
    return np.radians(sd_deg) ** 2 * (float(p @ p) * np.eye(3) - np.outer(p, p))


def node_covariance_sources(uncertainty: NodeUncertainty, calibration: StereoCalibration, probe: ProbeModel,
                            chain: ChainCalibration, earth_from_imu, tip_camera, axis_camera, *, window_camera=None,
                            insertion_sd_mm: float | None = None) -> dict[str, np.ndarray]:
    """Each source's own term, (3, 3) mm^2 in the trocar frame, keyed by :data:`SOURCES`, for a node stored at
    ``tip_camera`` (3,) mm with the probe's ``axis_camera`` (3,) (tip to body), the IMU at ``earth_from_imu`` (3, 3)
    and ``chain`` (at the insertion it was mapped with). ``window_camera`` (n, 3): the store window's fixes (camera
    frame), None when unknown; ``insertion_sd_mm``: the tracked insertion's sd, None while it is not tracked.

    Why one by one: each term is linear in its own magnitude's square, so the terms add up to the node's covariance
    and say which source to improve (the app's advice); :data:`PART_OF` groups them into
    :func:`node_covariance_parts`."""
    tip = np.asarray(tip_camera, float).reshape(3)
    u = uncertainty
    camera_to_trocar = trocar_from_camera(chain, earth_from_imu)
    R = camera_to_trocar[:3, :3]
    window = np.zeros((3, 3))
    if window_camera is not None:
        fixes = np.asarray(window_camera, float).reshape(-1, 3)
        if len(fixes) > 1:
            window = np.pi / 2.0 * np.cov(fixes, rowvar=False) / len(fixes)
    turned = np.degrees(Rotation.from_matrix(R @ reference_rotation(chain.shaft_camera).T).magnitude())
    imu_sd = u.imu_deg * min(turned / SMALLEST_TESTED_TURN_DEG, 1.0)
    node = camera_to_trocar[:3, :3] @ tip + camera_to_trocar[:3, 3]
    slide = u.insertion_sd_mm if insertion_sd_mm is None else float(insertion_sd_mm)
    shaft = R @ chain.shaft_camera
    along_shaft = np.outer(shaft, shaft)
    in_camera = {"image": tip_covariance(calibration, probe, tip, axis_camera, u.image_sd_px),
                 "residual": u.residual_mm**2 * np.eye(3), "window": window,
                 "pointing": pointing_covariance(axis_camera, u.pointing_lateral_mm, u.pointing_axial_mm)}
    return {**{name: R @ term @ R.T for name, term in in_camera.items()},
            "imu": orientation_covariance(node, imu_sd),
            "imu_camera": orientation_covariance(node, u.imu_camera_deg / np.sqrt(3.0)),
            "trocar_camera": u.trocar_camera_sd_mm**2 * along_shaft, "insertion": slide**2 * along_shaft}


def node_covariance_parts(uncertainty: NodeUncertainty, calibration: StereoCalibration, probe: ProbeModel,
                          chain: ChainCalibration, earth_from_imu, tip_camera, axis_camera, *, window_camera=None,
                          insertion_sd_mm: float | None = None) -> dict[str, np.ndarray]:
    """``{"tracking", "pointing", "chain"}``: each (3, 3) mm^2 in the trocar frame, the sums of
    :func:`node_covariance_sources` (same arguments) as :data:`PART_OF` groups them."""
    sources = node_covariance_sources(uncertainty, calibration, probe, chain, earth_from_imu, tip_camera, axis_camera,
                                      window_camera=window_camera, insertion_sd_mm=insertion_sd_mm)
    parts = {part: np.zeros((3, 3)) for part in dict.fromkeys(PART_OF.values())}
    for name, term in sources.items():
        parts[PART_OF[name]] += term
    return parts


def node_covariance(uncertainty: NodeUncertainty, calibration: StereoCalibration, probe: ProbeModel,
                    chain: ChainCalibration, earth_from_imu, tip_camera, axis_camera, *, window_camera=None,
                    insertion_sd_mm: float | None = None) -> np.ndarray:
    """(3, 3) mm^2, trocar frame: the sum of :func:`node_covariance_parts` (same arguments)."""
    parts = node_covariance_parts(uncertainty, calibration, probe, chain, earth_from_imu, tip_camera, axis_camera,
                                  window_camera=window_camera, insertion_sd_mm=insertion_sd_mm)
    return summed_covariance(parts)


def summed_covariance(terms: dict[str, np.ndarray]) -> np.ndarray:
    """(3, 3) mm^2: the terms of :func:`node_covariance_parts` or :func:`node_covariance_sources` added up, made
    exactly symmetric (the node's covariance)."""
    total = sum(terms.values())
    return 0.5 * (total + total.T)


def inside_ellipsoid(offsets, covariances, level: float = ELLIPSOID_LEVEL) -> np.ndarray:
    """(N,) bool: whether each offset (N, 3) mm (a node's actual error) lies inside its own ``level`` ellipsoid of
    ``covariances`` (N, 3, 3) mm^2: squared Mahalanobis distance within the chi-square quantile with 3 degrees of
    freedom (6.25 at 90 %)."""
    offsets = np.asarray(offsets, float).reshape(-1, 3)
    covariances = np.asarray(covariances, float).reshape(-1, 3, 3)
    distance2 = np.einsum("ni,ni->n", offsets, np.linalg.solve(covariances, offsets[:, :, None])[..., 0])
    return distance2 <= chi2.ppf(level, 3)


def ellipsoid_radius_mm(covariance, level: float = ELLIPSOID_LEVEL) -> float:
    """The longest semi-axis (mm) of the ``level`` ellipsoid of ``covariance`` (3, 3) mm^2: "within x mm (90 %)" in the
    least certain direction; NaN when the covariance is unknown."""
    matrix = np.asarray(covariance, float).reshape(3, 3)
    if not np.all(np.isfinite(matrix)):
        return float("nan")
    return float(np.sqrt(chi2.ppf(level, 3) * max(np.linalg.eigvalsh(matrix)[-1], 0.0)))


def _unit(vector) -> np.ndarray:
    v = np.asarray(vector, float).reshape(3)
    norm = float(np.linalg.norm(v))
    if not (np.isfinite(norm) and norm > 0):
        raise ValueError(f"the probe's axis must be a finite non-zero direction, got {v.tolist()}")
    return v / norm
