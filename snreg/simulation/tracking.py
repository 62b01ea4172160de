"""The tracking accuracy experiment (thesis §5.2, Table 4) on rendered frames.

Per depth band: four probe positions 40 mm apart (corners of a 40 mm square in the x-z
plane spanning the band), ``frames`` noisy frames of each. Reported per tracker: the RMS
+- std of the error of the measured 40 mm steps (frame k at one corner against frame k
at the next), the per-axis std of repeated measurements (precision), the RMS error
against the rendered ground truth (accuracy, which the thesis could not measure), and
the fraction of frames tracked. The position is the stripe-band centre on the axis
(the tip for the stereo trackers is in ``tip_rms_mm``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.camera import StereoCalibration
from snreg.demo.renderer import ProbePose, RenderOptions, StereoRenderer
from snreg.probe import ProbeModel
from snreg.tracking.stereo import StereoTracker, TrackingError

__all__ = ["BandResult", "run_tracking_experiment", "format_table", "THESIS_BANDS"]

THESIS_BANDS = ((70, 110), (90, 130), (130, 170), (170, 210), (210, 250), (250, 290))
TRACKERS = ("triangulation", "sgbm", "width")
_AXIS = np.array([1.0, -0.35, 0.4])        # probe pointing right, up and away: a typical side view


@dataclass(frozen=True)
class BandResult:
    band: tuple[int, int]
    tracker: str
    step_rms_mm: float
    step_std_mm: float
    axis_std_mm: np.ndarray     # (3,) per-axis std of repeated measurements
    rms_mm: float               # centre error against ground truth
    tip_rms_mm: float
    tracked: float              # fraction of frames with a fix


def band_poses(band: tuple[int, int], probe: ProbeModel) -> list[ProbePose]:
    """Four tip positions 40 mm apart: the corners of a square in the x-z plane across the band."""
    mid = 0.5 * (band[0] + band[1])
    axis = _AXIS / np.linalg.norm(_AXIS)
    corners = [(-20.0, -20.0), (20.0, -20.0), (20.0, 20.0), (-20.0, 20.0)]
    # place the stripe-band centre, not the tip, on the corners so the probe stays in view
    return [ProbePose.make(np.array([x, 0.0, mid + z]) - probe.band_centre_mm * axis, axis) for x, z in corners]


def _measure(tracker: StereoTracker, name: str, left, right):
    try:
        fix = tracker.marker_width(left) if name == "width" else tracker.track(left, right)
    except TrackingError:
        return None
    return fix


def run_tracking_experiment(calibration: StereoCalibration, probe: ProbeModel, bands=THESIS_BANDS, frames: int = 60,
                            noise_sigma: float = 3.0, seed: int = 0, progress=None) -> list[BandResult]:
    renderer = StereoRenderer(calibration, probe, texture_seed=seed + 7)
    trackers = {"triangulation": StereoTracker(calibration, probe, method="triangulation"),
                "sgbm": StereoTracker(calibration, probe, method="sgbm")}
    trackers["width"] = trackers["triangulation"]
    results = []
    for b, band in enumerate(bands):
        poses = band_poses(band, probe)
        centres = {n: np.full((len(poses), frames, 3), np.nan) for n in TRACKERS}
        tips = {n: np.full((len(poses), frames, 3), np.nan) for n in TRACKERS}
        for p, pose in enumerate(poses):
            radiance = renderer.radiance(pose, RenderOptions(seed=seed))
            for f in range(frames):
                left, right = renderer.expose(radiance, RenderOptions(noise_sigma=noise_sigma, seed=seed * 100003 + b * 1009 + p * 101 + f))
                for name in TRACKERS:
                    fix = _measure(trackers[name], name, left, right)
                    if fix is not None:
                        centres[name][p, f], tips[name][p, f] = fix.centre, fix.tip
                if progress:
                    progress(((b * len(poses)) + p) * frames + f + 1, len(bands) * len(poses) * frames)
        truth_c = np.array([pose.point(probe.band_centre_mm) for pose in poses])
        truth_t = np.array([pose.tip for pose in poses])
        for name in TRACKERS:
            c, t = centres[name], tips[name]
            steps = (c[1:] - c[:-1]) - (truth_c[1:] - truth_c[:-1])[:, None, :]
            step_err = np.linalg.norm(steps, axis=-1).ravel()
            step_err = step_err[np.isfinite(step_err)]
            err = np.linalg.norm(c - truth_c[:, None], axis=-1).ravel()
            tip_err = np.linalg.norm(t - truth_t[:, None], axis=-1).ravel()
            ok = np.isfinite(err)
            with np.errstate(invalid="ignore"):
                axis_std = np.nanmean(np.nanstd(c, axis=1), axis=0) if ok.any() else np.full(3, np.nan)
            results.append(BandResult(
                band, name,
                float(np.sqrt(np.mean(step_err**2))) if len(step_err) else float("nan"),
                float(np.std(step_err)) if len(step_err) else float("nan"),
                axis_std,
                float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else float("nan"),
                float(np.sqrt(np.mean(tip_err[ok] ** 2))) if ok.any() else float("nan"),
                float(ok.mean())))
    return results


def format_table(results: list[BandResult]) -> str:
    """Markdown: thesis Table 4 columns (step RMS +- std, per-axis std) and our accuracy columns."""
    header = ("| depth (mm) | tracker | step error RMS ± std (mm) | per-axis std [x y z] (mm) | "
              "centre error RMS (mm) | tip error RMS (mm) | tracked |")
    lines = [header, "|---|---|---|---|---|---|---|"]
    for r in results:
        axis = " ".join(f"{v:.2f}" for v in r.axis_std_mm)
        tip = "-" if r.tracker == "width" else f"{r.tip_rms_mm:.2f}"   # the width method has no 3D axis, hence no tip
        lines.append(f"| {r.band[0]}-{r.band[1]} | {r.tracker} | {r.step_rms_mm:.2f} ± {r.step_std_mm:.2f} | [{axis}] | "
                     f"{r.rms_mm:.2f} | {tip} | {100 * r.tracked:.0f}% |")
    return "\n".join(lines)
