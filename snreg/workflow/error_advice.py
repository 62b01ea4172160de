"""Which error source to improve: the stored nodes' covariances split by source, and the one that dominates, in words.

Why: a node's covariance (:func:`~snreg.tracking.uncertainty.node_covariance_sources`) is a sum of independent terms,
each the square of one magnitude (the stereo image noise, the tracker's residual, the probe's pointing, the IMU, the
IMU-camera angle, ...). When one term holds most of the stored nodes' error, the operator should hear which, and
whether anything on the rig lowers it (issue 28: "the IMU-camera angle: redo the trocar wizard"); when none does, or
no node's terms are known, nothing is said.

A source dominates when it holds at least :data:`DOMINANT_SHARE` of the nodes' error variance (the covariances'
traces, summed over the nodes) and :data:`RUNNER_UP_FACTOR` times the next source's. What halving it would do is
said as the nodes' median 90 % radius (:func:`~snreg.tracking.uncertainty.ellipsoid_radius_mm`) now and with that
source's sd halved (its term quartered), the other terms as they are.

>>> advice_text([acquisition.error_sources[i] for i in ids])
'Mostly the IMU-camera angle (71 % of the stored nodes' error variance): redo the trocar wizard ...'
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snreg.tracking.uncertainty import SOURCES, ellipsoid_radius_mm

__all__ = ["Dominant", "dominant_source", "advice_text", "SOURCE_WORDS", "DOMINANT_SHARE", "RUNNER_UP_FACTOR"]

DOMINANT_SHARE = 0.5
RUNNER_UP_FACTOR = 2.0
# source: (what it is, what lowers it), for the operator
SOURCE_WORDS = {
    "image": ("the stereo fix along the cameras' viewing rays",
              "store the nodes nearer the camera (that error grows with the square of the depth) or recalibrate the "
              "cameras"),
    "residual": ("the tracker's residual (lighting, segmentation of the stripes)",
                 "no setting lowers it; more nodes, spread apart, weigh it down in the fit"),
    "window": ("the probe moving while its node was stored",
               "hold the probe still while storing (a lower spread limit refuses a moving store)"),
    "pointing": ("the probe's pointing (the node within its radius of the axis and ahead of its tip)",
                 "it comes with the probe's size; nothing to redo"),
    "imu": ("the IMU's turn error at the nodes' distance from the pivot",
            "it comes with the IMU; check that it sits firmly on the endoscope"),
    "imu_camera": ("the IMU-camera angle", "redo the trocar wizard (it measures the IMU-camera rotation)"),
    "trocar_camera": ("the trocar-camera distance", "redo the trocar wizard"),
    "insertion": ("the camera's insertion (its slide in the trocar)",
                  "track it (Devices > Track the camera's insertion) or keep the camera from sliding"),
}


@dataclass(frozen=True)
class Dominant:
    """The dominant source, its share of the nodes' error variance (0-1), and the nodes' median 90 % radius (mm) now
    and with that source's sd halved."""

    source: str
    share: float
    radius_mm: float
    halved_mm: float


def dominant_source(per_node: list[dict[str, np.ndarray]]) -> Dominant | None:
    """The source that dominates the error of the nodes whose terms are given (one dict per node: source -> (3, 3)
    mm^2, as :func:`~snreg.tracking.uncertainty.node_covariance_sources` gives), or None: no node, or no source
    holds :data:`DOMINANT_SHARE` of the variance and :data:`RUNNER_UP_FACTOR` times the next one's."""
    if not per_node:
        return None
    variance = {source: sum(float(np.trace(terms[source])) for terms in per_node) for source in SOURCES}
    total = sum(variance.values())
    if not total > 0:
        return None
    first, second = sorted(SOURCES, key=variance.get, reverse=True)[:2]
    if variance[first] < DOMINANT_SHARE * total or variance[first] < RUNNER_UP_FACTOR * variance[second]:
        return None
    now = [ellipsoid_radius_mm(sum(terms.values())) for terms in per_node]
    halved = [ellipsoid_radius_mm(sum(terms.values()) - 0.75 * terms[first]) for terms in per_node]
    return Dominant(first, variance[first] / total, float(np.median(now)), float(np.median(halved)))


def advice_text(per_node: list[dict[str, np.ndarray]], of: str = "the stored nodes' error variance") -> str:
    """One sentence naming the dominant source, its share ``of`` the nodes' error variance (how to say which nodes),
    what lowers it and what halving it would do; "" when none dominates (or no node's terms are known)."""
    dominant = dominant_source(per_node)
    if dominant is None:
        return ""
    what, remedy = SOURCE_WORDS[dominant.source]
    return (f"Mostly {what} ({100 * dominant.share:.0f} % of {of}): {remedy}. Halved, it would bring "
            f"their 90 % radius from {dominant.radius_mm:.1f} to {dominant.halved_mm:.1f} mm (median).")
