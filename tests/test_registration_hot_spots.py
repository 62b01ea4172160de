"""Hot-spot pairing (docs/design.md, Contracts): several removed nodes may come from one SPECT hot spot, a node beyond every hot
spot's reach came from none, and a noisy fit that leans past a bound is fitted within it rather than refused."""

import numpy as np
import pytest

from snreg import geometry
from snreg.registration import CONFIDENT, METHODS, NoFitError, register
from snreg.registration._bounded import fit_within_bounds
from snreg.registration._problem import make_problem
from snreg.registration.naming import pair_text
from snreg.registration.report import pair_table

TRUTH = geometry.transform_from_euler(20.0, -10.0, 15.0, [10.0, -6.0, 12.0])


def case(xyz, noise=1.0, seed=0):
    return geometry.apply(TRUTH, xyz) + np.random.default_rng(seed).normal(0.0, noise, xyz.shape)


@pytest.mark.parametrize("method", METHODS)
def test_two_nodes_from_one_hot_spot_both_claim_it(method, pelvic_nodes):
    # a node 9-13 mm beside the node of P3 lit up with it on the SPECT: both came from P3, and say so
    xyz, _ = pelvic_nodes
    intraop = case(xyz)
    beside = intraop[2] + np.array([8.0, -7.0, 6.0])
    result = register(xyz, np.vstack([intraop, beside]), method=method)
    np.testing.assert_array_equal(result.pairing, [0, 1, 2, 3, 4, 5, 2])
    np.testing.assert_array_equal(result.shares, [False, False, True, False, False, False, True])
    assert not result.missing.any()
    assert np.all(result.confident), result.confidence
    rows = pair_table(result, ["P1", "P2", "P3", "P4", "P5", "P6"], [f"SN{k}" for k in range(1, 8)])
    assert pair_text(rows[6]) == "SN7 -> P3 (with SN3)" and pair_text(rows[2]) == "SN3 -> P3 (with SN7)"
    assert pair_text(rows[0]) == "SN1 -> P1"


def test_an_extra_nearer_the_hot_spot_than_its_true_node_leaves_both_right(pelvic_nodes):
    # the swap that the one-to-one rule got wrong: the true node of P2 lies 7.5 mm off, the extra (5-7 mm per axis
    # from it, as the thesis makes them) 3 mm from where P2 maps; whichever is P2's own, both came from P2
    xyz, _ = pelvic_nodes
    intraop = case(xyz, noise=0.5, seed=2)
    intraop[1] = geometry.apply(TRUTH, xyz[1]) + np.array([5.0, -4.0, 4.0])
    extra = intraop[1] + np.array([-7.0, 6.0, -5.0])
    result = register(xyz, np.vstack([intraop, extra]))
    np.testing.assert_array_equal(result.pairing, [0, 1, 2, 3, 4, 5, 1])
    assert result.shares[1] and result.shares[-1]
    assert result.confidence[-1] >= CONFIDENT
    # node 1 is likely the extra (its true node lies off): an extra may lie 5-15 mm per axis beside P1's node too, so
    # at this low noise (claims weighed at the model's own temperature) the model leaves ~4 % on P1: high, not certain
    assert 0.9 <= result.confidence[1] < result.confidence[-1]


def test_a_node_beyond_every_hot_spots_reach_came_from_none(pelvic_nodes):
    # 48 mm from the nearest hot spot, P6 not found: the node is from no imaged hot spot and P6 stays missing
    xyz, _ = pelvic_nodes
    found = case(xyz[:5], noise=1.5, seed=3)
    far = geometry.apply(TRUTH, xyz[5:]) + np.array([[-30.0, 25.0, -28.0]])
    result = register(xyz, np.vstack([found, far]))
    np.testing.assert_array_equal(result.pairing, [0, 1, 2, 3, 4, -1])
    np.testing.assert_array_equal(result.missing, [False] * 5 + [True])
    assert result.confidence[-1] > 0.5
    assert result.rms_mm < 4.0                       # the rms counts the nodes from a hot spot
    rows = pair_table(result, [f"P{k}" for k in range(1, 7)], [f"SN{k}" for k in range(1, 7)])
    assert pair_text(rows[5]) == "SN6 -> none"


@pytest.mark.parametrize("method", METHODS)
def test_a_noisy_fit_that_leans_past_the_rotation_bound_is_fitted_within_it(method):
    # three nodes turned 35 degrees with a 40 degree bound: the noise tips the exact three-node fit past 40 degrees
    # (issue 20: the true transform lies inside, so this is a result with its confidence, not NoFitError)
    preop = np.array([[0.0, 0.0, 0.0], [60.0, 0.0, 0.0], [10.0, 45.0, 0.0]])
    turn = geometry.transform_from_euler(35.0, 0.0, 0.0)
    noise = np.array([[2.0, -4.0, 0.0], [-1.0, 7.0, 0.0], [3.0, -1.0, 0.0]])
    intraop = geometry.apply(turn, preop) + noise
    problem = make_problem(preop, intraop, max_rotation_deg=40.0)
    free = geometry.kabsch(problem.preop, intraop)
    assert geometry.rotation_angle_deg(free) > 40.0              # the unconstrained fit leaves the bound
    result = register(preop, intraop, method=method, max_rotation_deg=40.0)
    np.testing.assert_array_equal(result.pairing, [0, 1, 2])
    assert geometry.rotation_angle_deg(result.transform) <= 40.0 + 1e-6
    assert geometry.rotation_angle_deg(result.transform) > 38.0   # it rests on the bound, or next to it


def test_the_fit_within_bounds_is_the_least_squares_fit_on_the_bound():
    # against a dense search of rotations on the bound and translations on theirs
    rng = np.random.default_rng(8)
    source = rng.uniform(-50.0, 50.0, (5, 3))
    target = geometry.apply(geometry.transform_from_euler(50.0, 20.0, -10.0, [40.0, 0.0, 10.0]), source)
    problem = make_problem(source, target, max_rotation_deg=30.0, max_translation_mm=20.0)
    fitted = fit_within_bounds(problem, problem.preop, target)
    angle, shift = problem.correction_size(fitted)
    assert angle <= 30.0 + 1e-6 and shift <= 20.0 + 1e-6
    best = np.sum((geometry.apply(fitted, problem.preop) - target) ** 2)
    from scipy.spatial.transform import Rotation
    axes = Rotation.random(4000, random_state=1).as_rotvec()
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    centre = problem.centre
    for rotvec in axes * np.radians(30.0):
        rotation = Rotation.from_rotvec(rotvec).as_matrix()
        wanted = (target - centre - (problem.preop - centre) @ rotation.T).mean(axis=0)
        wanted *= min(1.0, 20.0 / np.linalg.norm(wanted))
        trial = np.sum(((problem.preop - centre) @ rotation.T + centre + wanted - target) ** 2)
        assert best <= trial + 1e-6


def test_a_session_turned_far_beyond_the_bounds_is_still_refused(pelvic_nodes):
    # issue 11's far-off case: nodes turned 120 degrees, identity initial; no pairing inside 60 degrees explains them
    xyz, _ = pelvic_nodes
    far = geometry.transform_from_euler(120.0, 10.0, -5.0, [40.0, -20.0, 30.0])
    with pytest.raises(NoFitError, match="fit far better"):
        register(xyz, geometry.apply(far, xyz) + np.random.default_rng(1).normal(0.0, 1.0, xyz.shape))


def test_a_shared_hot_spot_reaches_the_csv_the_json_the_summary_and_the_session(pelvic_nodes, tmp_path):
    import csv

    import h5py

    from snreg.nodes import NodeSet
    from snreg.registration.report import pair_rows, summary_line, write_pairs_csv
    from snreg.session import Session

    xyz, labels = pelvic_nodes
    intraop_xyz = case(xyz)
    intraop_xyz = np.vstack([intraop_xyz, intraop_xyz[2] + np.array([8.0, -7.0, 6.0])])
    preop = NodeSet.from_xyz(xyz, labels, prefix="P")
    intraop = NodeSet.from_xyz(intraop_xyz, prefix="SN")
    result = register(preop.xyz, intraop.xyz)
    rows = pair_rows(preop, intraop, result)
    assert rows[6].as_json()["preop_id"] == "P3" and rows[6].as_json()["shared_with"] == ["SN3"]
    assert "7 of 7 intraop nodes from a hot spot, 1 hot spot with several" in summary_line(result, rows)
    lines = write_pairs_csv(tmp_path / "pairs.csv", preop, intraop, result).read_text(encoding="utf-8").splitlines()
    table = list(csv.DictReader(line for line in lines if not line.startswith("#")))
    assert [(r["intraop_id"], r["hot_spot"], r["shared_with"]) for r in table if r["shared_with"]] == [
        ("SN3", "P3", "SN7"), ("SN7", "P3", "SN3")]
    with Session.create(tmp_path / "s.h5", case_id="hot-spots") as session:
        n = session.add_registration(result, preop.ids, intraop.ids)
    with h5py.File(tmp_path / "s.h5", "r") as h5:
        np.testing.assert_array_equal(h5[f"registration/{n}/shares"][()], result.shares)
    stored = Session.open(tmp_path / "s.h5").registrations()[-1].result
    np.testing.assert_array_equal(stored.shares, result.shares)
