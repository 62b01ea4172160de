"""The gravity prior (issue 30): registration starts from the two downs and the centroids, searches every heading,
keeps the tilt near gravity's; bad downs refused in one sentence; without down nothing changes."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from snreg import geometry
from snreg.registration import NoFitError, register
from snreg.simulation.cohort import synthetic_cohort
from snreg.simulation.protocol import make_trial

DOWN_LPS = np.array([0.0, np.cos(np.radians(30.0)), np.sin(np.radians(30.0))])   # supine, 30 degrees head down


def turned_case(seed, heading_deg, sigma=3.0):
    """A patient's nodes, and the intraop frame turned ``heading_deg`` about gravity and shifted far away."""
    rng = np.random.default_rng(seed)
    preop = synthetic_cohort()[seed % 13].nodes.xyz
    intra_down = np.array([0.0, 0.0, -1.0])
    turn = (Rotation.from_rotvec(np.radians(heading_deg) * intra_down)
            * Rotation.align_vectors(intra_down[None], DOWN_LPS[None])[0])
    intraop_from_preop = geometry.make_transform(turn.as_matrix(), rng.uniform(-250, 250, 3))
    intraop = geometry.apply(intraop_from_preop, preop) + rng.normal(0, sigma, preop.shape)
    return preop, intraop, intra_down, intraop_from_preop


@pytest.mark.parametrize("heading", [0.0, 95.0, 180.0, 275.0])
def test_any_heading_and_a_far_shift_register_from_gravity(heading):
    preop, intraop, intra_down, truth = turned_case(4, heading)
    tilted = Rotation.from_rotvec(np.radians([4.0, -3.0, 0.0])).apply(DOWN_LPS)      # the tilt entered 5 degrees off
    result = register(preop, intraop, down=(tilted, intra_down))
    np.testing.assert_array_equal(result.pairing, np.arange(len(preop)))
    best = geometry.kabsch(preop, intraop)              # the least-squares fit of the true pairs
    assert np.degrees(Rotation.from_matrix(result.transform[:3, :3] @ best[:3, :3].T).magnitude()) < 1.0
    assert np.degrees(Rotation.from_matrix(result.transform[:3, :3] @ truth[:3, :3].T).magnitude()) < 15.0
    try:                                                # from the identity the same nodes are out of reach
        wrong = not np.array_equal(register(preop, intraop).pairing, np.arange(len(preop)))
    except NoFitError:
        wrong = True
    assert wrong


def test_an_initial_alignment_overrides_gravity():
    preop, intraop, intra_down, truth = turned_case(2, 120.0)
    given = register(preop, intraop, initial=truth, down=(DOWN_LPS, intra_down))
    plain = register(preop, intraop, initial=truth)
    np.testing.assert_array_equal(given.transform, plain.transform)
    np.testing.assert_array_equal(given.initial, truth)


def test_downs_that_disagree_far_beyond_their_sd_find_no_fit_in_words():
    preop, intraop, intra_down, _ = turned_case(4, 40.0)                                # six nodes
    wrong = Rotation.from_rotvec(np.radians([90.0, 0.0, 0.0])).apply(DOWN_LPS)        # a patient on their side
    with pytest.raises(NoFitError, match="gravity"):
        register(preop, intraop, down=(wrong, intra_down), down_sd_deg=5.0)


@pytest.mark.parametrize("down, sd, words", [
    (([0.0, 0.0, 0.0], [0.0, 0.0, -1.0]), 10.0, "preop vector is zero"),
    (([0.0, 1.0, 0.0], [np.nan, 0.0, -1.0]), 10.0, "NaN"),
    (([0.0, 1.0, 0.0],), 10.0, "pair of vectors"),
    (([0.0, 1.0, 0.0], [0.0, 0.0, -1.0]), 0.0, "down_sd_deg"),
    (([0.0, 1.0, 0.0], [0.0, 0.0, -1.0]), 90.0, "down_sd_deg"),
])
def test_bad_downs_are_refused_in_one_sentence(down, sd, words):
    preop, intraop, _, _ = turned_case(1, 10.0)
    with pytest.raises(ValueError, match=words):
        register(preop, intraop, down=down, down_sd_deg=sd)


def test_the_gravity_study_trial_turns_the_preop_set_any_way_and_gives_both_downs():
    patient = synthetic_cohort()[5]
    trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 2.0, 1, 0, (3,), start="gravity",
                       tilt_sd_deg=0.0, imu_down_sd_deg=0.0)
    pre_down, intra_down = trial.down
    moved_from_original = geometry.invert(trial.intraop_from_moved)
    np.testing.assert_allclose(moved_from_original[:3, :3] @ intra_down, pre_down, atol=1e-9)
    result = register(trial.moved_preop, trial.intraop, down=trial.down)
    true = trial.truth >= 0
    np.testing.assert_array_equal(result.pairing[true], trial.truth[true])
