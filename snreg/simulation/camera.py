"""The insertion tracker's accuracy experiment: rendered surgery videos whose insertion is known (issue 27).

Each trial renders a :class:`~snreg.demo.surgery_video.SurgeryVideo` of the thesis' rig (Appendix A calibration,
at ``scale`` of 1920x1080): tissue with its own relief and texture (drawn from the trial's seed) 50-130 mm ahead,
the camera sliding up to +-40 mm and turning up to 30 degrees about the pivot at up to 5 mm and 3 degrees per pair
and coming back to its start, the probe moving in view, sensor noise, the IMU at 0.2 degrees of noise, and a few
pairs covered (uniform) or blurred. The tracker is run as ``snreg track-camera`` runs it
(:func:`~snreg.workflow.insertion.follow_insertion`, the probe found in each pair), and each trial reports the
error over tracked pairs, how often textured pairs were lost, whether every hidden pair was lost, how far the end
is from the start insertion, and how often the error lies within twice the reported standard error. Speed is
``snreg bench``'s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from snreg.camera import thesis_calibration
from snreg.demo.camera_path import surgery_path
from snreg.demo.surgery_video import SurgeryVideo, VideoOptions, surgery_chain
from snreg.demo.tissue import TissueScene, TissueSurface
from snreg.probe import default_probe_model
from snreg.workflow.insertion import follow_insertion

__all__ = ["CameraTrial", "run_camera_trial", "format_camera_table", "summary"]

START_MM = 158.0


@dataclass(frozen=True, eq=False)
class CameraTrial:
    """One rendered video: absolute errors (mm) over tracked textured pairs, textured pairs lost of all textured,
    hidden pairs lost of all hidden, tracked hidden pairs' errors, the last pair's error (the video ends at its start
    pose), and the standard errors the tracker reported for the tracked textured pairs."""

    seed: int
    errors_mm: np.ndarray
    textured: int
    textured_lost: int
    hidden: int
    hidden_lost: int
    end_error_mm: float
    sd_mm: np.ndarray


def run_camera_trial(seed: int, *, pairs: int = 100, scale: float = 1.0, hidden: int = 4,
                     progress: Callable[[int, int], None] | None = None) -> CameraTrial:
    """Render and track one video of about ``pairs`` pairs, ``hidden`` of them covered or blurred (half each)."""
    calibration = thesis_calibration().scaled(scale) if scale != 1.0 else thesis_calibration()
    probe = default_probe_model()
    chain = surgery_chain(START_MM)
    rng = np.random.default_rng([seed, 271])
    surface = TissueSurface(depth_mm=rng.uniform(235.0, 255.0), relief_mm=rng.uniform(1.5, 5.0),
                            tilt_deg=tuple(rng.uniform(-12.0, 12.0, 2)), seed=seed, texture_seed=1000 + seed)
    path = surgery_path(pairs, START_MM, seed=seed)
    chosen = rng.choice(np.arange(3, len(path) - 3), hidden, replace=False)
    options = VideoOptions(covered=tuple(int(k) for k in chosen[::2]), blurred=tuple(int(k) for k in chosen[1::2]),
                           seed=seed)
    video = SurgeryVideo(TissueScene(calibration, probe, surface), path, chain, options)

    def rendered():
        for k in range(len(video)):
            if progress is not None:
                progress(k + 1, len(video))
            yield video.pair(k)

    estimates = list(follow_insertion(rendered(), (video.earth_from_imu(k) for k in range(len(video))), calibration,
                                      chain, probe))
    truth = video.path.insertion_mm
    hidden_pairs = np.array([options.hidden(k) for k in range(len(video))])
    tracked = np.array([e.tracked for e in estimates])
    values = np.array([e.trocar_camera_mm for e in estimates])
    errors = np.abs(values - truth)
    return CameraTrial(seed, errors[tracked & ~hidden_pairs], int((~hidden_pairs).sum()),
                       int((~tracked & ~hidden_pairs).sum()), int(hidden_pairs.sum()),
                       int((~tracked & hidden_pairs).sum()), float(errors[-1]) if tracked[-1] else float("nan"),
                       np.array([e.change_sd_mm for e in estimates])[tracked & ~hidden_pairs])


def summary(trials: list[CameraTrial]) -> dict:
    """The figures over all trials: error median / p95 / max (mm), textured pairs lost (%), hidden pairs lost (%),
    the worst end-to-start error (mm) and how often the error is within twice the reported standard error (%)."""
    errors = np.concatenate([t.errors_mm for t in trials])
    sds = np.concatenate([t.sd_mm for t in trials])
    textured = sum(t.textured for t in trials)
    hidden = sum(t.hidden for t in trials)
    return {"pairs": int(sum(t.textured + t.hidden for t in trials)),
            "error_median_mm": float(np.median(errors)), "error_p95_mm": float(np.percentile(errors, 95)),
            "error_max_mm": float(errors.max()),
            "textured_lost_percent": 100.0 * sum(t.textured_lost for t in trials) / max(textured, 1),
            "hidden_lost_percent": 100.0 * sum(t.hidden_lost for t in trials) / max(hidden, 1),
            "end_error_max_mm": float(np.nanmax([t.end_error_mm for t in trials])),
            "ends_lost": int(sum(not np.isfinite(t.end_error_mm) for t in trials)),
            "within_2sd_percent": 100.0 * float(np.mean(errors <= 2.0 * sds))}


def format_camera_table(trials: list[CameraTrial]) -> str:
    """A markdown table, one row per trial and one for all."""
    lines = ["| seed | pairs | error median / p95 / max (mm) | textured lost | hidden lost | end vs start (mm) | "
             "error within 2 sd |", "|---|---|---|---|---|---|---|"]
    for t in trials + [None]:
        group = trials if t is None else [t]
        s = summary(group)
        end = "lost" if s["ends_lost"] else f"{s['end_error_max_mm']:.2f}"
        lines.append(f"| {'all' if t is None else t.seed} | {s['pairs']} | {s['error_median_mm']:.3f} / "
                     f"{s['error_p95_mm']:.3f} / {s['error_max_mm']:.3f} | {s['textured_lost_percent']:.1f} % | "
                     f"{s['hidden_lost_percent']:.0f} % | {end} | {s['within_2sd_percent']:.0f} % |")
    return "\n".join(lines)
