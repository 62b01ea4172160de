"""Guidance towards missing SPECT nodes, on a seeded registration with two nodes not found."""

import numpy as np
import pytest

from snreg import geometry
from snreg.nodes import NodeSet
from snreg.registration import register
from snreg.registration.report import missing_nodes
from snreg.workflow.guidance import guidance_line, point_to_nearest, targets_text


def test_missing_nodes_are_listed_where_the_registration_maps_them_and_the_nearest_is_pointed_at(pelvic_nodes):
    xyz, labels = pelvic_nodes
    truth = geometry.transform_from_euler(15.0, 5.0, -10.0, [20.0, -10.0, 5.0])
    preop = NodeSet.from_xyz(xyz, labels, prefix="P")
    intraop = geometry.apply(truth, xyz) + np.random.default_rng(2).normal(0.0, 1.0, xyz.shape)
    result = register(xyz, intraop[[0, 1, 3, 5]])
    targets = missing_nodes(preop, result)
    assert [t.preop_id for t in targets] == ["P3", "P5"]
    truly = geometry.apply(truth, xyz)
    for t in targets:
        assert np.linalg.norm(t.mapped_xyz - truly[t.preop_index]) < t.bound_mm
    assert "P3 INT R" in targets_text(targets) and "P5 OBT L" in targets_text(targets)
    tip = truly[4] + np.array([0.0, 0.0, -30.0])                # 30 mm below P5 along -z
    pointer = point_to_nearest(targets, tip)
    assert pointer.target.preop_id == "P5" and abs(pointer.distance_mm - 30.0) < 5.0
    assert pointer.direction_words().startswith("+z") and not pointer.within_bound
    assert guidance_line(targets, tip).startswith("nearest missing P5: ")
    assert "inside its bound" in guidance_line(targets, targets[1].mapped_xyz)
    assert guidance_line(targets, None) == "nearest missing node: no probe fix"
    assert guidance_line([], tip) == "" and targets_text([]) == "every SPECT node is paired"


def test_a_missing_node_is_drawn_as_a_circle_sized_by_its_bound_at_its_depth():
    from snreg.registration.report import MissingNode
    from snreg.workflow.guidance import target_circle

    focal, centre_px = 1000.0, np.array([960.0, 540.0])

    def pinhole(points):
        return focal * points[:, :2] / points[:, 2:] + centre_px

    node = MissingNode(0, "P1", "OBT R", np.array([10.0, -20.0, 200.0]), 20.0)
    centre, radius = target_circle(node, np.eye(4), pinhole)
    np.testing.assert_allclose(centre, centre_px + focal * np.array([10.0, -20.0]) / 200.0)
    assert radius == pytest.approx(focal * 20.0 / 200.0, rel=0.01)          # 20 mm at 200 mm: 100 px
    moved = geometry.make_transform(np.eye(3), [0.0, 0.0, 200.0])           # twice as deep: half the circle
    assert target_circle(node, moved, pinhole)[1] == pytest.approx(radius / 2.0, rel=0.02)
    behind = geometry.make_transform(np.eye(3), [0.0, 0.0, -300.0])
    assert target_circle(node, behind, pinhole) is None
