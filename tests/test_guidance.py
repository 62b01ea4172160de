"""The list of missing SPECT nodes, on a seeded registration with two nodes not found."""

import numpy as np

from snreg import geometry
from snreg.nodes import NodeSet
from snreg.registration import register
from snreg.registration.report import missing_nodes
from snreg.workflow.guidance import targets_text


def test_missing_nodes_are_listed_where_the_registration_maps_them(pelvic_nodes):
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
    assert " of (" not in targets_text(targets, where=False)
    assert targets_text([]) == "every SPECT node is paired"
