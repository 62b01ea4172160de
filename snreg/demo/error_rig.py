"""The demo rig under an error model (``snreg demo --errors``, ``snreg-gui --demo --errors``): one seeded draw of the
model, turned into what the rig changes.

Why: the demo shows that the chain runs; with the thesis' error model it should also show what the set-up can
achieve. The rig runs what it can through its own code paths: the rendered frames get the model's sensor noise and
blur and are tracked live, tracking uses a calibration solved from noisy board corners, the SPECT is written with the
model's voxel size, resolution and counts at the sources' positions before the tissue shifted, then segmented. The
rest (pointing, the tracker's residual, the IMU's error at a camera turn the demo's still endoscope never makes, the
chain's distances, the camera's insertion) moves the rendered probe by what the same draw of
:func:`~snreg.demo.error_draws.compose` makes it cost in the budget, so the demo and ``snreg budget`` err alike. The
surgery demo's camera really turns and slides and its IMU really turns, so there the IMU's and the camera's errors
are what the simulated IMU, its fusion and the insertion tracker make, not drawn.
"""

from __future__ import annotations

import numpy as np

from snreg.camera import StereoCalibration
from snreg.demo.error_draws import camera_displacements, draw_errors, fused_imu_errors, phantom_geometry
from snreg.demo.error_stages import estimate_calibration
from snreg.demo.errors import ErrorModel
from snreg.demo.phantom import NOMINAL_TILT_DEG
from snreg.probe import ProbeModel

__all__ = ["DemoErrors", "INJECTED", "INJECTED_MOVING"]

INJECTED = ("pointing", "tracking", "imu", "chain", "camera")   # moved into the rendered pose (tracking: residual only)
INJECTED_MOVING = ("pointing", "tracking", "chain")             # the surgery demo: its camera and IMU turn for real


class DemoErrors:
    """One draw of ``model`` for the demo rig: the calibration tracking uses, the probe's offset on each node, the
    render noise, the SPECT's settings and the nodes' shift between scan and surgery."""

    def __init__(self, model: ErrorModel, probe: ProbeModel, cameras_full: StereoCalibration, *, scale: float,
                 seed: int, injected: tuple[str, ...] = INJECTED):
        """``injected``: the sources moved into the rendered pose (a rig whose camera really turns and slides, with an
        IMU that really turns, leaves "imu" and "camera" out: :data:`INJECTED_MOVING`)."""
        self.model = model
        geometry = phantom_geometry(probe)
        rotations = fused_imu_errors(model, geometry, seed) if "imu" in injected else None   # a simulated session
        draw = draw_errors(model, geometry, np.random.default_rng([seed, 5]), imu=rotations)     # (the same draws)
        self.tip_offsets_mm = camera_displacements(model, geometry, draw, injected)
        self.scan_shift_mm = model.on("tissue") * draw.tissue
        calibration = model.values["calibration"]
        self.calibration = None
        if model.on("calibration") and calibration["corner_noise_px"] > 0:
            self.calibration = estimate_calibration(cameras_full, views=int(calibration["views"]),
                                                    corner_noise_px=calibration["corner_noise_px"],
                                                    seed=seed).scaled(scale)
        tracking = model.values["tracking"]
        self.noise_sigma, self.blur_px = float(tracking["noise_sigma"]), float(tracking["blur_px"]) * scale
        spect = model.values["spect"]
        self.spect = {"voxel_mm": spect["voxel_mm"], "fwhm_mm": spect["fwhm_mm"], "peak_counts": spect["peak_counts"]}
        t = model.on("tissue")
        self.setup_deg = (NOMINAL_TILT_DEG + t * model["tissue", "setup_tilt_deg"], t * model["tissue", "setup_turn_deg"])
