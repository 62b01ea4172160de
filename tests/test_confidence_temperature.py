"""The claims' temperature follows the noise the best fit shows (snreg.registration.confidence.claim_temperature)."""

import numpy as np

from snreg import geometry
from snreg.registration import register
from snreg.registration._methods import METHOD_TABLE
from snreg.registration._problem import make_problem
from snreg.registration.confidence import NOISE_MM, SCORE_TEMPERATURE, claim_temperature, posterior_weights

PELVIS = np.array([[-55.0, 20.0, 30.0], [-45.0, 42.0, 8.0], [-47.0, 78.0, 50.0],
                   [52.0, 18.0, 35.0], [44.0, 45.0, 12.0], [12.0, 100.0, 72.0]])
TRUTH = geometry.transform_from_euler(5.0, -4.0, 3.0, translation=(4.0, -3.0, 2.0))


def _temperature(sigma_mm: float, seed: int) -> float:
    rng = np.random.default_rng(seed)
    intraop = geometry.apply(TRUTH, PELVIS) + rng.normal(0.0, sigma_mm, PELVIS.shape)
    problem = make_problem(PELVIS, intraop)
    fit = METHOD_TABLE["global"].fit(problem, {})
    ranked, _ = posterior_weights(fit.candidates)
    return claim_temperature(fit.problem, ranked[0])


def test_the_model_weighs_claims_as_it_scores_them_at_low_noise_and_halves_the_differences_at_high_noise():
    for seed in (1, 2, 3):
        assert _temperature(1.0, seed) == 1.0
        assert _temperature(25.0, seed) == SCORE_TEMPERATURE
    between = _temperature(np.mean(NOISE_MM) * 1.05, 4)
    assert 1.0 <= between <= SCORE_TEMPERATURE


def test_a_lone_node_of_its_side_is_claimed_confidently_once_the_fit_shows_little_noise():
    # three of four nodes in a pattern symmetric left/right, sides typed: the lone left node could be either left hot
    # spot, and 2 mm of noise leaves no doubt which; halving the score differences (temperature 2 at any noise) put
    # this claim below 0.95
    preop = np.array([[-30.0, 0.0, 0.0], [-28.0, 12.0, 26.0], [30.0, 0.0, 0.0], [28.0, 12.0, 26.0]])
    rng = np.random.default_rng(7)
    intraop = geometry.apply(TRUTH, preop[[0, 2, 3]]) + rng.normal(0.0, 2.0, (3, 3))
    result = register(preop, intraop, preop_labels=["L", "L", "R", "R"], intraop_labels=["EXT L", "EXT R", "OBT R"],
                      intraop_cov=np.repeat(4.0 * np.eye(3)[None], 3, axis=0))
    assert result.pairing.tolist() == [0, 2, 3]
    assert np.all(result.confidence >= 0.95), result.confidence
