"""The pivot distance from turns over rendered tissue: how close it comes, and how it degrades with less turn
(issue 27, self-calibration).

Each trial renders one cycle of the camera turning about the trocar over tissue
(:class:`~snreg.demo.tissue_pivot.TissuePivotScene`) on the thesis' rig (Appendix A calibration at ``scale`` of
1920x1080): the seed draws the true trocar-camera distance (130-180 mm), the tissue (60-110 mm ahead, its relief,
tilt and texture) and the sensor and IMU noise (0.2 degrees per axis); the shaft's orientation spread is ``turn_deg``
(an ellipse of tilts, 0.6 as wide one way as the other), the probe moves in view. The pairs are followed and fitted
as ``snreg calibrate trocar tissue`` does (:func:`~snreg.workflow.tissue_capture.follow_tissue`, the probe tracked in
each pair; :func:`~snreg.calibration.trocar_fit.fit_tissue_pivot`), and each trial reports the distance's error, its
standard error, the verdict and the IMU-camera rotation's error.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from snreg.calibration.trocar_fit import fit_tissue_pivot
from snreg.camera import thesis_calibration
from snreg.demo.tissue import TissueSurface
from snreg.demo.tissue_pivot import TissuePivotScene
from snreg.geometry import rotation_distance_deg
from snreg.probe import default_probe_model
from snreg.workflow.tissue_capture import follow_tissue

__all__ = ["TissuePivotTrial", "run_tissue_pivot_trial", "format_tissue_pivot_table", "summary"]


@dataclass(frozen=True)
class TissuePivotTrial:
    """One rendered turn: the true and measured distance (NaN when none), its standard error, the verdict ("none"
    when no pivot could be fitted), the views found of the pairs, and the IMU-camera rotation's error (degrees, NaN
    when not determined)."""

    seed: int
    turn_deg: float
    truth_mm: float
    distance_mm: float
    sd_mm: float
    verdict: str
    views: int
    pairs: int
    rotation_error_deg: float

    @property
    def error_mm(self) -> float:
        return self.distance_mm - self.truth_mm


def run_tissue_pivot_trial(seed: int, turn_deg: float, *, pairs: int = 36, scale: float = 0.5,
                           progress: Callable[[int, int], None] | None = None) -> TissuePivotTrial:
    """Render ``pairs`` pairs of one turn of spread ``turn_deg`` (degrees) over the seed's tissue and fit its pivot."""
    calibration = thesis_calibration().scaled(scale) if scale != 1.0 else thesis_calibration()
    rng = np.random.default_rng([seed, 313])
    truth = float(rng.uniform(130.0, 180.0))
    surface = TissueSurface(depth_mm=truth + rng.uniform(60.0, 110.0), relief_mm=rng.uniform(1.5, 5.0),
                            relief_scale_mm=rng.uniform(6.0, 14.0), tilt_deg=tuple(rng.uniform(-12.0, 12.0, 2)),
                            seed=seed, texture_seed=2000 + seed)
    tilt = 0.5 * turn_deg
    scene = TissuePivotScene(calibration, frames_per_cycle=pairs, tilt_deg=(tilt, 0.6 * tilt), trocar_camera_mm=truth,
                             surface=surface, seed=seed)

    def rendered():
        for k in range(pairs):
            if progress is not None:
                progress(k + 1, pairs)
            yield scene.render(k)

    poses = list(follow_tissue(rendered(), calibration, default_probe_model()))
    tracked = [k for k, pose in enumerate(poses) if pose.tracked]
    fit = fit_tissue_pivot(np.array([poses[k].tissue_from_camera for k in tracked]).reshape(-1, 4, 4),
                           np.array([scene.earth_from_imu(k) for k in tracked]).reshape(-1, 3, 3))
    if fit.pivot is None:
        return TissuePivotTrial(seed, turn_deg, truth, float("nan"), float("nan"), "none", len(tracked), pairs,
                                float("nan"))
    rotation_error = (float(rotation_distance_deg(fit.chain.imu_from_camera, scene.true_chain.imu_from_camera))
                      if fit.hand_eye is not None else float("nan"))
    return TissuePivotTrial(seed, turn_deg, truth, fit.pivot.trocar_camera_mm, fit.pivot.distance_sd_mm,
                            fit.pivot.verdict, len(tracked), pairs, rotation_error)


def summary(trials: list[TissuePivotTrial]) -> dict:
    """The figures of a group of trials: |error| median and max (mm), median standard error (mm), the verdicts'
    counts, views found (%) and the largest IMU-camera rotation error (degrees)."""
    errors = np.abs([t.error_mm for t in trials])
    verdicts = {v: sum(t.verdict == v for t in trials) for v in ("good", "check", "bad", "none")}
    return {"trials": len(trials), "error_median_mm": float(np.nanmedian(errors)) if np.isfinite(errors).any() else None,
            "error_max_mm": float(np.nanmax(errors)) if np.isfinite(errors).any() else None,
            "sd_median_mm": float(np.nanmedian([t.sd_mm for t in trials])) if np.isfinite(errors).any() else None,
            "verdicts": verdicts, "views_percent": 100.0 * sum(t.views for t in trials) / sum(t.pairs for t in trials),
            "rotation_error_max_deg": (float(np.nanmax([t.rotation_error_deg for t in trials]))
                                       if np.isfinite([t.rotation_error_deg for t in trials]).any() else None)}


def format_tissue_pivot_table(trials: list[TissuePivotTrial]) -> str:
    """A markdown table: one row per trial, then one per turn over all seeds."""
    lines = ["| seed | turn (deg) | truth (mm) | measured (mm) | error (mm) | standard error (mm) | views | verdict | "
             "IMU-camera error (deg) |", "|---|---|---|---|---|---|---|---|---|"]
    for t in trials:
        lines.append(f"| {t.seed} | {t.turn_deg:g} | {t.truth_mm:.2f} | {t.distance_mm:.2f} | {t.error_mm:+.2f} | "
                     f"{t.sd_mm:.2f} | {t.views}/{t.pairs} | {t.verdict} | {t.rotation_error_deg:.2f} |")
    lines += ["", "| turn (deg) | trials | error median / max (mm) | standard error median (mm) | good / check / bad | "
                  "IMU-camera error max (deg) |", "|---|---|---|---|---|---|"]
    for turn in sorted({t.turn_deg for t in trials}, reverse=True):
        s = summary([t for t in trials if t.turn_deg == turn])
        v = s["verdicts"]
        figures = ("-" if s["error_median_mm"] is None else
                   f"{s['error_median_mm']:.2f} / {s['error_max_mm']:.2f} | {s['sd_median_mm']:.2f}")
        rotation = "-" if s["rotation_error_max_deg"] is None else f"{s['rotation_error_max_deg']:.2f}"
        lines.append(f"| {turn:g} | {s['trials']} | {figures} | {v['good']} / {v['check']} / {v['bad'] + v['none']} | "
                     f"{rotation} |")
    return "\n".join(lines)
