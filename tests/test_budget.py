"""The error budget (issue 22): the error model and its files, the draws composed through the chain, switching a source
off, the Fitzpatrick-West prediction, the Monte Carlo's structure, ``snreg budget``'s refusals and the demo's errors."""

import json

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.stats import binom, chi2

from snreg.camera import thesis_calibration
from snreg.cli import main
from snreg.demo.error_draws import compose, draw_errors, phantom_geometry
from snreg.demo.error_rig import DemoErrors
from snreg.demo.errors import PARAMETERS, SOURCES, load_error_model
from snreg.demo.phantom import true_sources_lps
from snreg.demo.scene import phantom_tips
from snreg.chain import ChainCalibration
from snreg.probe import default_probe_model
from snreg.registration.target import rigid_fit_covariance
from snreg.simulation.budget import BudgetConfig, run_budget
from snreg.simulation.budget_report import markdown_report, plot_tornado

PROBE = default_probe_model()
GEOMETRY = phantom_geometry(PROBE)


@pytest.mark.parametrize("name", ["ideal", "thesis"])
def test_shipped_models_cite_every_magnitude(name):
    model = load_error_model(name)
    assert model.name == name and set(model.values) == set(SOURCES)
    cited = {(s, p) for s in SOURCES for p in PARAMETERS[s] if model.cite(s, p)}
    if name == "thesis":        # every parameter of every source, with where its number comes from
        assert cited == {(s, p) for s in SOURCES for p in PARAMETERS[s]}


def test_settings_scale_or_set_and_refuse_bad_names(tmp_path):
    model = load_error_model("thesis")
    assert model.with_setting("tracking=0.5").on("tracking") == 0.5
    changed = model.with_setting("imu.turn_error_deg=0.2")
    assert changed["imu", "turn_error_deg"] == 0.2 and model["imu", "turn_error_deg"] == 0.4625
    assert "--set" in changed.cite("imu", "turn_error_deg")
    for bad in ("nosuch=1", "tracking.nosuch=1", "tracking=-1", "tracking=lots", "imu.fusion=magic", "tracking",
                "spect.voxel_mm=0", "calibration.views=2.5"):
        with pytest.raises(ValueError):
            model.with_setting(bad)
    user = tmp_path / "mine.yaml"
    user.write_text("%YAML:1.0\n---\npointing:\n  lateral_mm: 2.0\n")
    mine = load_error_model(user)
    assert mine["pointing", "lateral_mm"] == 2.0 and mine["spect", "voxel_mm"] == 4.795     # the rest stays ideal
    user.write_text("%YAML:1.0\n---\npointing:\n  sideways_mm: 2.0\n")
    with pytest.raises(ValueError, match="sideways_mm"):
        load_error_model(user)


def test_cli_refuses_bad_settings_in_one_line(capsys, tmp_path):
    for argv in (["budget", "--set", "trakcing=0.5"], ["budget", "--set", "tracking.noise_sigma=-3"],
                 ["budget", "--errors", str(tmp_path / "none.yaml")], ["demo", "--headless", "-o",
                                                                       str(tmp_path / "d.h5"), "--errors", "nope"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("snreg: ") and "\n" not in err
    assert not (tmp_path / "d.h5").exists()


def _draw(model, seed=0):
    """A draw with stand-ins for the code-measured sources (an IMU rotation, a SPECT error)."""
    return draw_errors(model, GEOMETRY, np.random.default_rng(seed), imu=np.full((4, 3), 0.004),
                       spect=np.random.default_rng(seed + 1).normal(0, 1.0, (4, 3)))


def test_compose_without_errors_is_the_truth_and_each_source_moves_nodes():
    model = load_error_model("thesis")
    draw = _draw(model)
    none = compose(model.only([]), GEOMETRY, draw)
    np.testing.assert_allclose(none.node_errors, 0.0, atol=1e-9)
    for source in ("pointing", "tracking", "tissue", "chain", "spect"):
        assert np.abs(compose(model.only([source]), GEOMETRY, draw).node_errors).max() > 0.05, source
    # an IMU error and a camera turn interact: the turn alone costs nothing, with the IMU it moves the right nodes
    assert np.abs(compose(model.only(["camera"]), GEOMETRY, draw).node_errors).max() < 2.0
    both = compose(model.only(["camera", "imu"]), GEOMETRY, draw).node_errors
    imu = compose(model.only(["imu"]), GEOMETRY, draw).node_errors
    right = GEOMETRY.poses == 1
    assert np.linalg.norm(both[right] - imu[right], axis=1).min() > 1.0
    # scaling a source scales its error: half the pointing, half the node error it makes
    half = compose(model.only(["pointing"]).with_setting("pointing=0.5"), GEOMETRY, draw).node_errors
    full = compose(model.only(["pointing"]), GEOMETRY, draw).node_errors
    np.testing.assert_allclose(half, full / 2, atol=1e-9)


def test_a_tracked_insertion_leaves_the_tracker_error_instead_of_the_slide():
    model = load_error_model("thesis").with_setting("camera.insertion_sd_mm=20").only(["camera"])
    draw = _draw(model)
    assert np.abs(draw.insertion).max() > 2.0
    unseen = compose(model, GEOMETRY, draw).node_errors
    tracked = compose(model.with_setting("camera.insertion=tracked"), GEOMETRY, draw).node_errors
    # unseen, a node moves by its pose's slide along the camera axis; tracked, by the tracker's error alone
    assert np.linalg.norm(unseen, axis=1).max() > 0.8 * np.abs(draw.insertion).max()
    assert np.linalg.norm(tracked, axis=1).max() <= np.abs(draw.insertion_tracked).max() + 1e-9
    assert np.linalg.norm(tracked, axis=1).max() > 0.0


def test_rigid_fit_covariance_is_fitzpatrick_and_west():
    rng = np.random.default_rng(3)
    fiducials = rng.normal(0, 30, (5, 3))
    targets = rng.normal(0, 60, (4, 3))
    covariance = rigid_fit_covariance(fiducials, targets)
    centred = fiducials - fiducials.mean(axis=0)
    axes = np.linalg.svd(centred)[2]
    n = len(fiducials)
    for target, cov in zip(targets - fiducials.mean(axis=0), covariance):
        # TRE^2 = FLE^2 / N (1 + 1/3 sum d_k^2 / f_k^2), FLE^2 = 3 sigma^2 per axis (Fitzpatrick, West, Maurer 1998)
        d2 = [target @ target - (target @ a) ** 2 for a in axes]
        f2 = [np.mean(np.sum(centred**2, axis=1) - (centred @ a) ** 2) for a in axes]
        assert np.trace(cov) == pytest.approx(3.0 / n * (1 + sum(d / f for d, f in zip(d2, f2)) / 3), rel=1e-4)


@pytest.fixture(scope="module")
def small_budget():
    """Two repetitions over one rendered-tracking draw (1 frame per node, calibration from 6 views)."""
    model = (load_error_model("thesis").with_setting("tracking.frames=1").with_setting("calibration.views=6")
             .with_setting("tracking.method=triangulation"))
    config = BudgetConfig(reps=2, draws=1, imu_draws=1, workers=1, seed=4)
    return model, config, run_budget(model, config)


@pytest.mark.slow
def test_budget_reports_every_source_alone_and_all_but(small_budget, tmp_path):
    model, config, result = small_budget
    out = result.to_json()
    assert set(out) == {"all", "alone", "all_but", "tre_predicted_mm", "dominant"}
    assert set(out["alone"]) == set(out["all_but"]) == set(SOURCES) and out["dominant"] in SOURCES
    for figure in [out["all"], *out["alone"].values(), *out["all_but"].values()]:
        assert set(figure) == {"rms_mm", "node_error_mm", "pairing_success", "coverage_90"}
        assert set(figure["rms_mm"]) == set(figure["node_error_mm"]) == {"median", "p90"}
    assert result.figures["none"].rms_median < 0.5                 # nothing errs: only the method's own floor
    assert out["alone"]["calibration"]["node_error_mm"]["median"] > 0   # solved from noisy corners, then tracked
    assert out["alone"]["tracking"]["node_error_mm"]["median"] > 0
    assert out["tre_predicted_mm"] > 0 and json.dumps(out)
    # coverage: every node of every repetition judged (its value against what it should be: the covariance test below)
    assert all(len(figure.covered) == 4 * config.reps for figure in result.figures.values())
    assert out["all"]["coverage_90"] == round(result.figures["all"].coverage_90, 4)
    assert np.isfinite(result.figures["all"].covered).all() and out["alone"]["pointing"]["coverage_90"] is not None
    assert out["alone"]["spect"]["coverage_90"] is None         # no intraop error: no node has an ellipsoid
    text = markdown_report(result, "snreg budget --reps 2")
    assert "Dominant source" in text and "thesis Table 4" in text and "registered without the covariances" in text
    png = plot_tornado(result, tmp_path / "t.png")
    assert png.read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_switching_a_source_off_removes_exactly_its_contribution(small_budget):
    model, config, result = small_budget
    without = run_budget(model.with_setting("pointing=0").with_setting("tracking=0").with_setting("calibration=0"),
                         config)
    assert "pointing" not in without.to_json()["alone"]
    # the same draws: all sources but these three is what the full run measured for them off, node for node
    reference = run_budget(model.only([s for s in SOURCES if s not in ("pointing", "tracking", "calibration")]),
                           config).figures["all"]
    np.testing.assert_allclose(without.figures["all"].node_error_mm, reference.node_error_mm)
    assert np.median(without.figures["all"].node_error_mm) < np.median(result.figures["all"].node_error_mm)


def test_demo_errors_ideal_changes_nothing_and_thesis_moves_the_probe():
    cameras = thesis_calibration()
    ideal = DemoErrors(load_error_model("ideal"), PROBE, cameras, scale=0.5, seed=1)
    assert ideal.calibration is None and np.all(ideal.tip_offsets_mm == 0) and np.all(ideal.scan_shift_mm == 0)
    assert ideal.noise_sigma == 2.0 and ideal.blur_px == 0.0
    chain = ChainCalibration.manual()
    tips = phantom_tips(PROBE)
    np.testing.assert_allclose(true_sources_lps(tips, chain, setup_deg=ideal.setup_deg), true_sources_lps(tips, chain))
    thesis = DemoErrors(load_error_model("thesis"), PROBE, cameras, scale=0.5, seed=1)
    assert 1.0 < np.linalg.norm(thesis.tip_offsets_mm, axis=1).mean() < 20.0
    assert thesis.calibration is not None and thesis.calibration.image_size == (960, 540)
    assert thesis.spect["peak_counts"] == 141.0


def test_cli_states_the_library_defaults():
    """``snreg budget`` states its defaults itself so that building the parser imports no numpy."""
    from snreg.cli import budget as cli_budget
    from snreg.registration import METHODS
    from snreg.simulation import budget

    assert cli_budget.DEFAULT_REPS == budget.DEFAULT_REPS and cli_budget._METHODS == METHODS


@pytest.mark.slow
def test_cli_json_is_one_object_of_the_documented_shape(capsys, tmp_path):
    argv = ["budget", "--reps", "2", "--workers", "1", "--set", "tracking=0", "--set", "calibration=0", "--set", "imu=0",
            "--json", "--quiet", "-o", str(tmp_path / "out")]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"all", "alone", "all_but", "tre_predicted_mm", "dominant"}
    assert set(out["alone"]) == {"pointing", "chain", "spect", "tissue", "camera"}
    assert {p.name for p in (tmp_path / "out").iterdir()} == {"budget.md", "tornado.png", "budget.json"}


def test_cohort_runs_the_model_over_patient_like_node_sets():
    from snreg.simulation import synthetic_cohort

    patients = synthetic_cohort()[:2]
    cohort = tuple((p.nodes.xyz, tuple(p.nodes.labels)) for p in patients)
    model = load_error_model("thesis").with_setting("tracking=0").with_setting("calibration=0").with_setting("imu=0")
    result = run_budget(model, BudgetConfig(reps=2, workers=1, cohort=cohort))
    sizes = [len(p.nodes.xyz) for p in patients]
    assert len(result.figures["all"].node_error_mm) == sum(sizes)          # repetition r meets patient r
    assert result.figures["none"].rms_median < 0.5 and result.figures["all"].rms_median > 1.0
    assert "patient-like" in markdown_report(result)


def _within_sampling_noise(covered, p):
    """Whether the share of covered nodes lies within the two-sided 99.9 % binomial interval around ``p``."""
    low, high = binom.interval(0.999, len(covered), p)
    return low <= np.sum(covered) <= high


@pytest.mark.slow
def test_each_nodes_covariance_holds_its_error_and_the_budget_can_register_with_it():
    """The rig's covariance from the model's magnitudes: on one draw it is the function the acquisition runs; over a
    small run the 90 % ellipsoids hold the share of the nodes' intraop errors they should (pointing's uniform errors
their exact share, the Gaussian tracker residual's 90 %) within the binomial sampling noise; --covariances registers
with them."""
    from snreg.demo.error_covariance import intraop_covariances, node_uncertainty
    from snreg.tracking.uncertainty import NodeUncertainty, node_covariance

    model = load_error_model("thesis")
    mapped = node_uncertainty(model)               # the thesis model's magnitudes are the cited defaults
    assert mapped.imu_deg == pytest.approx(np.hypot(0.4625, 0.1167))
    assert mapped == NodeUncertainty(imu_deg=mapped.imu_deg)
    assert node_uncertainty(model.only(["pointing"])).residual_mm == 0.0
    scenario = compose(model, GEOMETRY, _draw(model))
    cameras = thesis_calibration()
    covariances = intraop_covariances(model, scenario, cameras, PROBE, GEOMETRY.axis_camera)
    np.testing.assert_allclose(covariances[2], node_covariance(
        node_uncertainty(model), cameras, PROBE, scenario.chains[2], scenario.earth_from_imu[2],
        scenario.tips_camera[2], GEOMETRY.axis_camera))
    # pointing alone: uniform within the probe's radius L and up to a ahead, its covariance L^2/4 across and a^2/3
    # along; its squared Mahalanobis distance is 4u + 3v^2 (u, v uniform), inside the 90 % ellipsoid with this chance
    limit = chi2.ppf(0.9, 3)
    expected = quad(lambda v: min(1.0, (limit - 3 * v * v) / 4), 0.0, 1.0)[0]
    assert 0.985 < expected < 0.99                     # lighter-tailed than a Gaussian: more than 90 % inside
    pointing = model.only(["pointing"]).with_setting("pointing=2")
    figure = run_budget(pointing, BudgetConfig(reps=30, workers=1, seed=3, method="icp")).figures["all"]
    assert len(figure.covered) == 120 and _within_sampling_noise(figure.covered, expected)
    # tracking alone: the tracker's residual, Gaussian, dominates; its ellipsoids hold 90 % of the errors
    tracking = model.only(["tracking"]).with_setting("tracking.frames=1")
    config = BudgetConfig(reps=30, draws=1, imu_draws=1, workers=1, seed=3, method="icp")
    figure = run_budget(tracking, config).figures["all"]
    assert len(figure.covered) == 120 and _within_sampling_noise(figure.covered, 0.9)
    with_cov = run_budget(pointing, BudgetConfig(reps=2, workers=1, method="global", covariances=True))
    assert "registration global with each node's covariance" in markdown_report(with_cov)
