"""Registration with SPECT nodes not (yet) found: partial pairing both ways, where the missing nodes are, how sure,
and bounds that are kept (issue: registration when nodes are still missing)."""

import numpy as np
import pytest

from snreg import geometry
from snreg.registration import CONFIDENT, METHODS, NoFitError, register
from snreg.registration.pairing import pairing_at
from snreg.simulation.cohort import synthetic_cohort
from snreg.simulation.protocol import make_trial

TRUTH = geometry.transform_from_euler(20.0, -10.0, 15.0, [10.0, -6.0, 12.0])


def test_found_nodes_and_an_extra_leave_the_unfound_preop_node_missing(pelvic_nodes):
    # issue 11's typical failure: the extra must not take the place of the SPECT node not found; 35 mm from it (20 mm
    # and more per axis), it lies beyond the reach of that hot spot, so it came from none
    xyz, _ = pelvic_nodes
    rng = np.random.default_rng(3)
    found = geometry.apply(TRUTH, xyz[:5]) + rng.normal(0.0, 1.5, (5, 3))
    extra = geometry.apply(TRUTH, xyz[5:]) + np.array([[-20.0, 18.0, -22.0]])
    result = register(xyz, np.vstack([found, extra]))
    np.testing.assert_array_equal(result.pairing, [0, 1, 2, 3, 4, -1])
    np.testing.assert_array_equal(result.missing, [False] * 5 + [True])
    assert result.rms_mm < 4.0


@pytest.mark.parametrize("method", METHODS)
def test_every_method_reports_missing_nodes_bounds_and_leave_one_out(method, pelvic_nodes):
    xyz, _ = pelvic_nodes
    intraop = geometry.apply(TRUTH, xyz) + np.random.default_rng(1).normal(0.0, 1.0, xyz.shape)
    result = register(xyz, intraop[[0, 1, 3, 5]], method=method)
    if method != "icp":              # the thesis' icp starts from the nearest pairs and is pulled off by the gaps
        np.testing.assert_array_equal(result.pairing, [0, 1, 3, 5])
        np.testing.assert_array_equal(result.missing, [False, False, True, False, True, False])
        mapped = geometry.apply(result.transform, xyz)
        true_place = geometry.apply(TRUTH, xyz)
        assert np.all(np.linalg.norm(mapped - true_place, axis=1)[[2, 4]] < result.target_error_mm[[2, 4]])
    assert result.target_error_mm.shape == (6,) and np.all(result.target_error_mm > 0)
    assert result.missing.shape == (6,) and result.missing.sum() == 6 - len(set(result.pairing) - {-1})
    assert result.leave_one_out_mm.shape == (4,)
    others = [len(set(result.pairing[result.pairing >= 0]) - {p}) for p in result.pairing]   # other hot spots found
    assert np.all(np.isfinite(result.leave_one_out_mm) == ((result.pairing >= 0) & (np.array(others) >= 3)))
    np.testing.assert_array_equal(result.initial, np.eye(4))


def test_the_target_error_bound_grows_with_the_noise_and_covers_left_out_nodes():
    # calibrated bounds: over seeded trials of the study's kind, left-out nodes fall inside their bound about 90% of
    # the time, and noisier cases get wider bounds
    patients = synthetic_cohort()
    covered, bounds = [], {5.0: [], 10.0: []}
    for sigma in (5.0, 10.0):
        for k, patient in enumerate(p for p in patients if len(p.nodes) >= 4):
            trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, sigma, 1, 0, (21, k, 1, 0),
                               n_missing=1)
            try:
                result = register(trial.moved_preop, trial.intraop)
            except NoFitError:
                continue
            mapped = geometry.apply(result.transform, trial.moved_preop)
            error = np.linalg.norm(mapped[trial.left_out] - trial.left_out_xyz, axis=1)
            covered += list(error <= result.target_error_mm[trial.left_out])
            bounds[sigma] += list(result.target_error_mm[trial.left_out])
    assert 0.7 <= np.mean(covered) <= 1.0
    assert np.median(bounds[10.0]) > 1.3 * np.median(bounds[5.0])


def test_leave_one_out_singles_out_a_displaced_node(pelvic_nodes):
    xyz, _ = pelvic_nodes
    intraop = geometry.apply(TRUTH, xyz)
    intraop[4] += np.array([6.0, -5.0, 4.0])               # 8.8 mm off: paired, but the others disagree with it
    result = register(xyz, intraop)
    assert result.pairing[4] == 4
    loo = result.leave_one_out_mm
    assert loo[4] > 8.0 and np.argmax(loo) == 4 and np.median(loo) < 3.0
    assert loo[4] > result.distances_mm[4]                 # the residual alone understates it


def test_an_extra_standing_where_no_preop_node_is_found_is_claimed_extra_with_confidence(pelvic_nodes):
    xyz, _ = pelvic_nodes
    intraop = geometry.apply(TRUTH, xyz) + np.random.default_rng(5).normal(0.0, 1.0, xyz.shape)
    far_extra = intraop.mean(axis=0) + np.array([[0.0, 0.0, 70.0]])
    result = register(xyz, np.vstack([intraop[:5], far_extra]))
    assert result.pairing[-1] == -1 and result.confidence[-1] >= CONFIDENT
    np.testing.assert_array_equal(result.missing, [False] * 5 + [True])


def test_impossible_bounds_refuse_instead_of_returning_a_transform(pelvic_nodes):
    xyz, _ = pelvic_nodes
    turned = geometry.apply(geometry.transform_from_euler(90.0, 0.0, 0.0, [5.0, 0.0, 0.0]), xyz)
    for method in METHODS:
        with pytest.raises(NoFitError, match="initial alignment"):
            register(xyz, turned, method=method, max_rotation_deg=5.0)
    assert issubclass(NoFitError, ValueError)
    rough = geometry.transform_from_euler(85.0, 3.0, -2.0, [3.0, 1.0, 0.0])      # a rough alignment makes it fit
    result = register(xyz, turned, max_rotation_deg=10.0, initial=rough)
    np.testing.assert_array_equal(result.pairing, np.arange(len(xyz)))
    np.testing.assert_array_equal(result.initial, rough)


def test_a_fit_far_better_beyond_the_bounds_refuses_the_forced_one_inside(pelvic_nodes):
    # 40 degrees off with 25 allowed: the hypotheses inside the bounds still pair something, but the nodes say the
    # bounds are wrong, so no forced pairing is returned
    xyz, _ = pelvic_nodes
    turned = geometry.apply(geometry.transform_from_euler(40.0, 0.0, 0.0), xyz)
    with pytest.raises(NoFitError, match="fit far better"):
        register(xyz, turned, max_rotation_deg=25.0)
    assert np.all(register(xyz, turned, max_rotation_deg=60.0).pairing == np.arange(len(xyz)))


def test_the_pairing_at_a_known_transform_leaves_a_far_node_to_none_and_lets_a_crowded_hot_spot_share(pelvic_nodes):
    # the model oracle of snreg simulate: with the transform known, a node 40 mm from every mapped node came from no
    # hot spot, and two nodes beside one preop node both came from it (docs/design.md, Contracts)
    xyz, _ = pelvic_nodes
    intraop = geometry.apply(TRUTH, xyz) + np.random.default_rng(4).normal(0.0, 1.0, xyz.shape)
    far = geometry.apply(TRUTH, xyz[:1]) + np.array([[40.0, 0.0, 0.0]])
    beside = geometry.apply(TRUTH, xyz[1:2]) + np.array([[7.0, -6.0, 5.0]])
    pairing = pairing_at(xyz, np.vstack([intraop, far, beside]), TRUTH, 2.0)
    np.testing.assert_array_equal(pairing, [0, 1, 2, 3, 4, 5, -1, 1])


# -- each node with its own covariance (issue 28) ------------------------------------------------------------------
def _anisotropic_case(seed, sigma=12.0, ratio=5.0, n_extra=1):
    """Nodes whose error along each one's viewing ray is ``ratio`` times the error across it (per-axis RMS ``sigma``),
    an extra beside a host as the thesis makes them, the preop set turned and shifted; with the true covariances."""
    rng = np.random.default_rng(seed)
    preop = rng.uniform([-70, -50, 0], [70, 30, 120], (6, 3))
    while np.min(np.linalg.norm(preop[:, None] - preop[None], axis=-1) + 1e9 * np.eye(6)) < 15:
        preop = rng.uniform([-70, -50, 0], [70, 30, 120], (6, 3))
    across = sigma / np.sqrt((ratio**2 + 2) / 3)
    tilt, turn = np.radians(40) * np.sqrt(rng.uniform(0, 1, 6)), rng.uniform(0, 2 * np.pi, 6)
    rays = np.c_[np.sin(tilt) * np.cos(turn), np.sin(tilt) * np.sin(turn), np.cos(tilt)]
    cov = across**2 * (np.eye(3) + (ratio**2 - 1) * rays[:, :, None] * rays[:, None, :])
    intraop = preop + np.einsum("mij,mj->mi", np.linalg.cholesky(cov), rng.standard_normal((6, 3)))
    hosts = rng.integers(0, 6, n_extra)
    intraop = np.vstack([intraop, intraop[hosts] + rng.uniform(5, 15, (n_extra, 3)) * rng.choice([-1, 1], (n_extra, 3))])
    cov = np.concatenate([cov, cov[hosts]])
    moved = geometry.apply(geometry.transform_from_euler(*rng.uniform(0, 20, 3), rng.uniform(-15, 15, 3)), preop)
    return moved, intraop, cov


def test_covariances_are_checked_and_a_scalar_is_one_sd_for_every_node():
    moved, intraop, cov = _anisotropic_case(1)
    for bad, words in ((cov[:3], r"must be \(7, 3, 3\)"), (-cov, "negative variance"), (np.full_like(cov, np.nan), "NaN"),
                       (cov + np.triu(np.ones(3), 1), "symmetric"), (-1.0, "from 0"), ("wide", "covariances in mm")):
        with pytest.raises(ValueError, match=words):
            register(moved, intraop, intraop_cov=bad)
    one = register(moved, intraop, intraop_cov=3.0)
    every = register(moved, intraop, intraop_cov=np.broadcast_to(9.0 * np.eye(3), (7, 3, 3)))
    np.testing.assert_allclose(one.transform, every.transform)
    np.testing.assert_array_equal(one.pairing, every.pairing)


@pytest.mark.slow
def test_covariances_pair_anisotropic_nodes_better_than_one_sigma():
    right = {False: 0, True: 0}
    for seed in range(30):
        moved, intraop, cov = _anisotropic_case(100 + seed, sigma=14.0)
        for given in right:
            result = register(moved, intraop, intraop_cov=cov if given else None)
            right[given] += bool(np.all(result.pairing[:6] == np.arange(6)))
    assert right[True] >= right[False] + 4, right


def test_the_weighted_fit_trusts_each_node_across_its_ray():
    """Errors only along the viewing rays: weighted by covariances that say so, the transform comes out near exact;
    Kabsch, weighing every direction alike, does not."""
    rng = np.random.default_rng(7)
    preop = rng.uniform(-60, 60, (6, 3))
    rays = rng.normal(size=(6, 3))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    intraop = preop + rng.normal(0, 8.0, (6, 1)) * rays                        # 8 mm along each ray, none across
    cov = 0.01 * np.eye(3) + 64.0 * rays[:, :, None] * rays[:, None, :]
    weighted = register(preop, intraop, intraop_cov=cov)
    plain = register(preop, intraop)
    assert np.abs(weighted.transform - np.eye(4)).max() < 0.02
    assert np.abs(plain.transform[:3, 3]).max() > 0.5
    np.testing.assert_array_equal(weighted.pairing, np.arange(6))
    assert np.all(np.isfinite(weighted.leave_one_out_mm)) and np.all(weighted.target_error_mm > 0)


@pytest.mark.slow
def test_target_error_bounds_with_covariances_cover_the_truth():
    inside, total = 0, 0
    for seed in range(20):
        rng = np.random.default_rng(300 + seed)
        moved, intraop, cov = _anisotropic_case(300 + seed, sigma=6.0, n_extra=0)
        keep = rng.permutation(6)[:4]                            # two SPECT nodes not found yet
        result = register(moved, intraop[keep], intraop_cov=cov[keep])
        missing = np.setdiff1d(np.arange(6), keep)
        mapped = geometry.apply(result.transform, moved[missing])
        actual = np.linalg.norm(mapped - intraop[missing], axis=1)       # from where they were stored
        inside += int(np.sum(actual <= result.target_error_mm[missing]))
        total += len(missing)
    assert inside >= 0.8 * total, (inside, total)
