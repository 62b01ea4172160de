"""Which error source to improve (issue 28): a node's covariance split by source adds up to it, and the advice names
a source only when it dominates the stored nodes' error, with what halving it would do."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg.camera import thesis_calibration
from snreg.chain import ChainCalibration
from snreg.demo.scene import PROBE_AXIS
from snreg.probe import default_probe_model
from snreg.tracking.uncertainty import (PART_OF, SOURCES, NodeUncertainty, ellipsoid_radius_mm, node_covariance,
                                        node_covariance_parts, node_covariance_sources)
from snreg.workflow.error_advice import DOMINANT_SHARE, advice_text, dominant_source

CAMERAS = thesis_calibration()
PROBE = default_probe_model()
CHAIN = ChainCalibration.manual().with_reference(np.eye(3))
TIPS = np.array([[-20.0, 5.0, 90.0], [15.0, -10.0, 80.0], [0.0, 20.0, 110.0], [25.0, 15.0, 95.0]])


def sources_at(uncertainty: NodeUncertainty, k: int, **options) -> dict:
    turn = Rotation.from_euler("ZYX", [8.0 * k, 3.0, -2.0], degrees=True).as_matrix()
    return node_covariance_sources(uncertainty, CAMERAS, PROBE, CHAIN, turn, TIPS[k], PROBE_AXIS, **options)


def test_the_sources_add_up_to_the_nodes_covariance_and_group_into_its_parts():
    uncertainty = NodeUncertainty(imu_camera_deg=1.0)
    window = np.random.default_rng(1).normal(TIPS[0], 0.4, (30, 3))
    turn = Rotation.from_euler("ZYX", [0.0, 3.0, -2.0], degrees=True).as_matrix()
    args = (uncertainty, CAMERAS, PROBE, CHAIN, turn, TIPS[0], PROBE_AXIS)
    sources = node_covariance_sources(*args, window_camera=window, insertion_sd_mm=0.2)
    assert set(sources) == set(SOURCES)
    np.testing.assert_allclose(sum(sources.values()), node_covariance(*args, window_camera=window, insertion_sd_mm=0.2),
                               atol=1e-12)
    parts = node_covariance_parts(*args, window_camera=window, insertion_sd_mm=0.2)
    for part, total in parts.items():
        np.testing.assert_allclose(sum(t for s, t in sources.items() if PART_OF[s] == part), total, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(sources["imu_camera"]) > -1e-12) and np.trace(sources["imu_camera"]) > 0


def test_at_the_cited_magnitudes_no_source_dominates_and_nothing_is_said():
    """The tracker's residual and the probe's pointing share the error about equally: no advice."""
    per_node = [sources_at(NodeUncertainty(), k) for k in range(4)]
    assert dominant_source(per_node) is None and advice_text(per_node) == ""
    assert advice_text([]) == ""


def test_a_large_imu_camera_angle_is_named_with_its_remedy_and_what_halving_it_does():
    per_node = [sources_at(NodeUncertainty(imu_camera_deg=4.0), k) for k in range(4)]
    dominant = dominant_source(per_node)
    assert dominant.source == "imu_camera" and dominant.share >= DOMINANT_SHARE
    now = np.median([ellipsoid_radius_mm(sum(s.values())) for s in per_node])
    assert dominant.radius_mm == pytest.approx(now) and dominant.halved_mm < 0.7 * now
    text = advice_text(per_node)
    assert text.startswith(f"Mostly the IMU-camera angle ({100 * dominant.share:.0f} % of the stored nodes' error "
                           "variance): redo the trocar wizard")
    assert f"from {dominant.radius_mm:.1f} to {dominant.halved_mm:.1f} mm (median)" in text


def test_a_source_just_ahead_of_the_next_does_not_dominate():
    """Half the variance is not enough when the next source holds more than half as much."""
    per_node = [{source: np.zeros((3, 3)) for source in SOURCES} for _ in range(2)]
    for terms in per_node:
        terms["residual"], terms["pointing"] = np.eye(3) * 6.0, np.eye(3) * 4.0
    assert dominant_source(per_node) is None
    for terms in per_node:
        terms["pointing"] = np.eye(3) * 2.9
    assert dominant_source(per_node).source == "residual"
