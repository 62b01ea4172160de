"""Each node's own covariance under an error model: the model's magnitudes mapped onto the rig's node uncertainty
(:mod:`snreg.tracking.uncertainty`), evaluated at the geometry each node was stored with.

Why: the budget (``snreg budget``) asks whether the ellipsoids the app would give its nodes hold their actual errors
(``coverage_90``) and whether registration gains from them. Both need the covariance the rig itself would compute,
from what it can know: the same function the acquisition runs at each store, fed with the model's cited magnitudes
(each scaled by its source's factor, as the draws are) and each node's measured tip, chain and IMU orientation. Only
what a rig could know goes in: no draw's own values. The store window's spread is not among them (the budget's
tracking draws keep only each node's median fix); the calibration's error has no term of its own (0.3 mm alone in the
thesis' budget); the tissue's shift is not the intraop measurement's error.
"""

from __future__ import annotations

import numpy as np

from snreg.camera import StereoCalibration
from snreg.demo.error_draws import Scenario
from snreg.demo.errors import ErrorModel
from snreg.probe import ProbeModel
from snreg.tracking.uncertainty import NodeUncertainty, node_covariance

__all__ = ["node_uncertainty", "intraop_covariances"]


def node_uncertainty(model: ErrorModel) -> NodeUncertainty:
    """The node uncertainty of ``model``: its tracker's residual, pointing, IMU turn error (mean and sd in quadrature:
    the turn error is drawn with either sign), chain and unseen insertion change, each times its source's scale; the
    image noise is :class:`NodeUncertainty`'s measured default on the model's rendered frames, times the tracking
    scale."""
    v, s = model.values, model.on
    turn_deg = float(np.hypot(v["imu"]["turn_error_deg"], v["imu"]["turn_error_sd_deg"]))
    return NodeUncertainty(image_sd_px=s("tracking") * NodeUncertainty.image_sd_px,
                           residual_mm=s("tracking") * v["tracking"]["residual_mm"],
                           pointing_lateral_mm=s("pointing") * v["pointing"]["lateral_mm"],
                           pointing_axial_mm=s("pointing") * v["pointing"]["axial_mm"],
                           imu_deg=s("imu") * turn_deg,
                           imu_camera_deg=s("chain") * v["chain"]["imu_camera_deg"],
                           trocar_camera_sd_mm=s("chain") * v["chain"]["trocar_camera_sd_mm"],
                           insertion_sd_mm=s("camera") * v["camera"]["insertion_sd_mm"])


def intraop_covariances(model: ErrorModel, scenario: Scenario, cameras: StereoCalibration, probe: ProbeModel,
                        axis_camera) -> np.ndarray:
    """(N, 3, 3) mm^2, trocar frame: each intraop node's covariance as the rig would compute it at its store, under
    ``model`` (its scaled sources), the calibrated ``cameras`` and the probe held along ``axis_camera`` (3,)."""
    uncertainty = node_uncertainty(model)
    tracked = model["camera", "insertion"] == "tracked"
    slide = model.on("camera") * model["camera", "tracked_sd_mm"] if tracked else None
    rig = zip(scenario.tips_camera, scenario.chains, scenario.earth_from_imu)
    return np.array([node_covariance(uncertainty, cameras, probe, chain, orientation, tip, axis_camera,
                                     insertion_sd_mm=slide) for tip, chain, orientation in rig])
