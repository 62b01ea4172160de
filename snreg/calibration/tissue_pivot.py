"""Pivot calibration from the camera turning over tissue: the trocar-camera distance with no board (issue 27, item 3).

Why: the board method (:mod:`snreg.calibration.pivot`) needs a checkerboard held still in front of the endoscope,
which is not there once the camera is in the patient, and the insertion changes in surgery. When the camera turns
about the trocar's pivot over still tissue, its free poses in a frame fixed to the tissue
(:class:`~snreg.odometry.poses.TissuePoseFollower`: metric, from the stereo pair alone) keep the pivot fixed exactly
as board poses do, so the same least-squares pivot fit (:func:`~snreg.calibration.pivot.pivot_calibration`) gives
``trocar_camera_mm`` with the tissue frame in the board's part; with the IMU's orientation per pose the same
rotation hand-eye (:func:`~snreg.calibration.pivot.imu_camera_rotation`) gives the IMU-camera rotation. The IMU
does not enter the distance: the camera's own rotation, from hundreds of tissue points over a wide view, is the
better measurement of the two (hundredths of a degree between neighbouring views, against the IMU's tenths).

The verdict says, in the terms of this recording, what the board method's says: too few views, too little turn
(the lever that turns pose noise into distance error), a residual that says the camera did not turn about one fixed
point (it slid through the trocar, or the trocar or the tissue moved), or views that disagree. Its standard error
assumes independent poses; poses measured through a chain of keyframes are not, and the error measured on rendered
tissue is up to several times the standard error, so the turn thresholds come from those measurements
(``snreg experiment tissue-pivot``, six scenes at half the thesis resolution): with a spread of 20 degrees the
distance was within 0.9 mm, with 12 within 1.4 mm, with 8 within 3.7 mm and with 4 within 4.3 mm.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from snreg.calibration.pivot import BAD_INLIER_FRACTION, PivotResult, pivot_calibration

__all__ = ["MIN_VIEWS", "GOOD_TURN_DEG", "BAD_TURN_DEG", "GOOD_RMS_MM", "BAD_RMS_MM", "GOOD_SD_MM", "BAD_SD_MM",
           "tissue_pivot_calibration"]

MIN_VIEWS = 8                            # fewer agreeing views: bad
GOOD_TURN_DEG, BAD_TURN_DEG = 12.0, 6.0  # spread of the shaft's direction over the views (module docstring)
GOOD_RMS_MM, BAD_RMS_MM = 0.6, 1.5       # RMS pivot residual (rendered tissue: 0.1-0.4 mm)
GOOD_SD_MM, BAD_SD_MM = 0.5, 1.5         # standard error of the distance


def tissue_pivot_calibration(tissue_from_camera: np.ndarray) -> PivotResult:
    """The pivot of free camera poses (n, 4, 4) ``tissue_from_camera`` (mm) over still tissue, with this method's
    verdict (module docstring) in place of the board's.

    ``pivot_board_mm`` is then the pivot in the tissue frame. Raises ``ValueError`` as
    :func:`~snreg.calibration.pivot.pivot_calibration` does (fewer than 4 poses, no turn, a turn about one axis).
    """
    pivot = pivot_calibration(tissue_from_camera)
    verdict, advice = _verdict(pivot)
    return replace(pivot, verdict=verdict, advice=advice)


def _verdict(pivot: PivotResult) -> tuple[str, str]:
    """("good" | "check" | "bad", one sentence) from the thresholds above."""
    rms, sd, turn, used = pivot.rms_mm, pivot.distance_sd_mm, pivot.tilt_range_deg, pivot.n_used
    if used < MIN_VIEWS:
        return "bad", (f"only {used} views agree on a pivot, {MIN_VIEWS} are needed; keep textured tissue in view, "
                       "turn the camera more slowly and record again")
    if turn < BAD_TURN_DEG:
        return "bad", (f"the camera turned through only {turn:.1f} degrees, under the {BAD_TURN_DEG:g} a distance "
                       "needs; turn it further about the trocar, left-right and up-down, and record again")
    if rms > BAD_RMS_MM or sd > BAD_SD_MM:
        return "bad", (f"residual {rms:.2f} mm, uncertainty {sd:.2f} mm: the camera did not turn about one fixed point "
                       "(it slid through the trocar, or the trocar or the tissue moved); hold the insertion and record "
                       "again")
    if pivot.inliers.mean() < BAD_INLIER_FRACTION:
        return "bad", (f"only {pivot.inliers.mean():.0%} of the views agree on one pivot: the tissue or the trocar "
                       "moved while recording; record again")
    if turn < GOOD_TURN_DEG:
        return "check", (f"residual {rms:.2f} mm, uncertainty {sd:.2f} mm over a turn of only {turn:.1f} degrees: "
                         f"usable, but a turn of {GOOD_TURN_DEG:g} degrees or more would be surer")
    if rms > GOOD_RMS_MM or sd > GOOD_SD_MM:
        return "check", (f"residual {rms:.2f} mm, uncertainty {sd:.2f} mm over a turn of {turn:.1f} degrees: usable, "
                         "but the camera may have slid a little or the tissue moved; hold the insertion over still "
                         "tissue and record again to be sure")
    return "good", f"residual {rms:.2f} mm, uncertainty {sd:.2f} mm over a turn of {turn:.1f} degrees in {used} views"
