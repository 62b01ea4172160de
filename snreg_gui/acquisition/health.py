"""The words and tone of the acquisition screen's stream health lines: the camera feed and the IMU.

Why apart: what each line says is a plain function of the newest result, the feed's age and the IMU's snapshot,
testable without a window; the screen only shows it every 250 ms. A stream that stopped says STALE in red, as the
camera's insertion says LOST (:mod:`snreg_gui.acquisition.insertion_line`).
"""

from __future__ import annotations

from snreg.imu.monitor import STALE_AFTER_S, ImuSnapshot
from snreg_gui.acquisition.status import BAD, PAUSED
from snreg_gui.acquisition.worker import FrameResult

_PROBLEMS = ("STALE", "DROPPED", "STOPPED", "not recorded")       # words of the camera line that make it red


def camera_health(result: FrameResult | None, age_s: float, paused: str = "", preparing: str = "") -> tuple[str, str]:
    """(text, style) of the camera line: frame rate, skew, what tracking costs per pair (the probe, and the
    insertion when it is tracked), STALE after :data:`STALE_AFTER_S` without frames, and the recording's state;
    ``paused``: why the feed is paused (a wizard has the cameras); ``preparing``: what the rig is still preparing
    (the demo's tour rendering), shown beside the rest."""
    if paused:
        return f"camera: {paused}", PAUSED
    besides = f" ({preparing})" if preparing else ""
    if result is None:
        return f"camera: waiting for frames{besides}", ""
    outcome = result.outcome
    stale = f"  STALE {age_s:.1f} s" if age_s > STALE_AFTER_S else ""
    insertion = f" + insertion {outcome.insertion_ms:.0f} ms" if outcome.insertion is not None else ""
    text = (f"camera: {result.fps:4.1f} fps, skew {result.skew_ms:+.1f} ms, tracking {outcome.track_ms:.0f} ms"
            f"{insertion}{stale}{besides}\n{outcome.video}")
    return text, BAD if any(word in text for word in _PROBLEMS) else ""


# the reader's states before its first sample: not started yet, or its port opening (it says STALE itself when the
# port stays silent, DISCONNECTED when it vanishes)
_BEFORE_FIRST_SAMPLE = ("stopped", "connecting")


def imu_health(imu: ImuSnapshot) -> tuple[str, str]:
    """(text, style) of the IMU line: state, rate, corrupt lines, STALE, the problem in words; "starting" before the
    first sample (an IMU that has sent nothing yet is not a stream that stopped)."""
    if imu.samples == 0 and imu.state in _BEFORE_FIRST_SAMPLE and not imu.problem:
        return "IMU: starting, no sample yet", ""
    stale = "  STALE" if imu.stale else ""
    problem = f" ({imu.problem})" if imu.problem else ""
    return f"IMU: {imu.state}, {imu.rate_hz:.0f} Hz, {imu.corrupt} corrupt{stale}{problem}", BAD if imu.stale else ""
