"""The synthetic cohort, the thesis protocol, statistics and the report."""

import csv

import numpy as np
import pytest

from snreg import geometry
from snreg.nodes import NodeSet, write_nodes
from snreg.simulation import StudyConfig, load_cohort, run_study, synthetic_cohort, write_report
from snreg.simulation.cohort import MIN_SEPARATION_MM, THESIS_NODE_COUNTS
from snreg.simulation.protocol import error_stats, make_trial, oracle_success
from snreg.simulation.stats import accuracy, threshold_for
from snreg.simulation.study import parse_method


def test_cohort_matches_thesis_table1():
    patients = synthetic_cohort()
    assert [len(p.nodes) for p in patients] == list(THESIS_NODE_COUNTS)
    for p in patients:
        d = np.linalg.norm(p.nodes.xyz[:, None] - p.nodes.xyz[None], axis=-1)
        assert d[np.triu_indices(len(d), 1)].min() >= MIN_SEPARATION_MM
        for label, xyz in zip(p.nodes.labels, p.nodes.xyz):
            station, side = label.split()
            assert side in "LR" and (xyz[0] > 0) == (side == "L")   # LPS: +x is the patient's left
    assert synthetic_cohort()[3].nodes.xyz.tolist() == patients[3].nodes.xyz.tolist()


def test_a_directory_of_csvs_replaces_the_cohort(tmp_path):
    write_nodes(NodeSet.from_xyz(np.eye(3) * 30, ["OBT R", "EXT L", "INT R"]), tmp_path / "a.csv")
    (tmp_path / "b.csv").write_text("id,label,x,y,z\nA,,0,0,0\nB,,1,1,1\n")
    with pytest.raises(ValueError, match="at least 3 nodes"):
        load_cohort(tmp_path)
    (tmp_path / "b.csv").unlink()
    assert [p.name for p in load_cohort(tmp_path)] == ["a"]
    with pytest.raises(ValueError, match="no node CSV"):
        load_cohort(tmp_path / "missing")


def test_trial_follows_the_protocol():
    patient = synthetic_cohort()[6]
    trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 5.0, 2, 0, (1, 2, 3))
    n = len(patient.nodes)
    assert len(trial.intraop) == n + 2 and np.sum(trial.truth == -1) == 2
    assert sorted(trial.truth[trial.truth >= 0]) == list(range(n))
    np.testing.assert_allclose(geometry.apply(trial.intraop_from_moved, trial.moved_preop), trial.preop, atol=1e-9)
    yaw, pitch, roll = geometry.euler_from_rotation(geometry.invert(trial.intraop_from_moved))
    assert all(0 <= a <= 30 for a in (yaw, pitch, roll))
    again = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 5.0, 2, 0, (1, 2, 3))
    np.testing.assert_array_equal(again.intraop, trial.intraop)


def test_extra_nodes_sit_5_to_15_mm_per_axis_from_a_true_node():
    patient = synthetic_cohort()[1]
    trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 0.0, 3, 0, (4,))
    true = trial.intraop[trial.truth >= 0]
    for extra in trial.intraop[trial.truth < 0]:
        offsets = np.abs(true - extra)
        assert np.any(np.all((offsets >= 5) & (offsets <= 15), axis=1))


def test_oracles_and_error_ratio_on_a_clean_trial():
    patient = synthetic_cohort()[0]
    trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 0.0, 0, 0, (5,))
    assert oracle_success(trial) == {"oracle_nearest": True, "oracle_one_to_one": True, "oracle_model": True,
                                     "oracle_nearest_all_claims": True, "oracle_nearest_cov": True}
    assert error_stats(trial)["max_error_ratio"] == 0.0


def test_an_anisotropic_trial_errs_along_each_nodes_ray_and_carries_its_covariances():
    patient = synthetic_cohort()[1]
    isotropic = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 6.0, 2, 0, (8,))
    again = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 6.0, 2, 0, (8,), anisotropy=1.0)
    np.testing.assert_array_equal(isotropic.intraop, again.intraop)         # the thesis' protocol unchanged
    np.testing.assert_allclose(isotropic.intraop_cov, 36.0 * np.eye(3)[None].repeat(len(isotropic.intraop), 0))
    trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 6.0, 2, 0, (8,), anisotropy=5.0)
    eigen = np.linalg.eigvalsh(trial.intraop_cov)
    np.testing.assert_allclose(eigen[:, 2] / eigen[:, 0], 25.0)             # sd 5 times larger along the ray
    np.testing.assert_allclose(eigen.sum(axis=1), 3 * 36.0)                 # per-axis RMS still sigma
    along, across = [], []
    for rep in range(12):
        trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 6.0, 0, rep, (8, rep), anisotropy=5.0)
        errors = trial.intraop - trial.preop[trial.truth]
        rays = np.linalg.eigh(trial.intraop_cov)[1][:, :, 2]
        along.append(np.einsum("ni,ni->n", errors, rays))
        across.append(errors - along[-1][:, None] * rays)
    along_rms = np.sqrt(np.mean(np.concatenate(along) ** 2))
    across_rms = np.sqrt(np.mean(np.concatenate(across) ** 2) * 3 / 2)      # per axis across the ray
    assert 3.5 < along_rms / across_rms < 7.0


def test_wilson_interval_and_threshold():
    acc = accuracy([True] * 95 + [False] * 5)
    assert acc.rate == 0.95 and acc.low == pytest.approx(0.8882, abs=1e-3) and acc.high == pytest.approx(0.9785, abs=1e-3)
    conf = np.array([0.99, 0.98, 0.97, 0.6, 0.5])
    right = np.array([True, True, True, False, True])
    threshold, precision, coverage = threshold_for(conf, right, precision=0.99)
    assert threshold == 0.97 and precision == 1.0 and coverage == 0.6


def test_parse_method():
    plain = {"use_labels": False, "use_cov": False, "use_landmarks": False}
    assert parse_method("global") == ("global", plain)
    assert parse_method("global+labels") == ("global", {**plain, "use_labels": True})
    assert parse_method("global+cov+labels") == ("global", {**plain, "use_labels": True, "use_cov": True})
    assert parse_method("global+landmarks") == ("global", {**plain, "use_landmarks": True})
    assert parse_method("cpd:w=0.1") == ("cpd", {**plain, "w": 0.1})
    assert parse_method("chamfer:form=volume") == ("chamfer", {**plain, "form": "volume"})
    with pytest.raises(ValueError):
        parse_method("global+magic")


@pytest.mark.slow
def test_small_study_is_reproducible_and_reports(tmp_path):
    patients = synthetic_cohort()[:3]
    config = StudyConfig(methods=("icp", "global"), sigmas=(2.0, 10.0), extras=(0, 1), reps=2, seed=3, workers=1)
    study = run_study(patients, config, progress=False)
    assert len(study.rows) == 3 * 2 * 2 * 2 * 2
    parallel = run_study(patients, StudyConfig(**{**config.__dict__, "workers": 2}), progress=False)
    assert [r["success"] for r in parallel.rows] == [r["success"] for r in study.rows]
    np.testing.assert_array_equal([r["rms_mm"] for r in parallel.rows], [r["rms_mm"] for r in study.rows])
    paths = write_report(study, tmp_path, "snreg simulate --reps 2")
    text = paths["markdown"].read_text()
    assert "Table 6 analogue" in text and "| 2 | 12 |" in text and "global - best oracle" in text
    with paths["trials"].open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == len(study.rows) and {"success", "rms_mm", "max_error_ratio", "oracle_nearest"} <= set(rows[0])
    for key in ("accuracy_plot", "error_ratio_plot", "calibration_plot"):
        assert paths[key].stat().st_size > 1000


def test_intraop_labels_keep_the_side_and_sometimes_miss_the_station():
    patient = synthetic_cohort()[6]
    same, total = 0, 0
    for rep in range(40):
        trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 2.0, 1, rep, (rep,))
        for m, n in enumerate(trial.truth):
            if n >= 0:
                pre, intra = trial.preop_labels[n].split(), trial.intraop_labels[m].split()
                assert pre[1] == intra[1]
                same += pre[0] == intra[0]
                total += 1
    assert 0.6 < same / total < 0.8    # STATION_ERROR = 0.3


@pytest.mark.slow
def test_a_study_with_missing_nodes_reports_them_per_count_with_coverage_and_the_incremental_scenario(tmp_path):
    patients = [p for p in synthetic_cohort() if len(p.nodes) >= 5][:2]
    config = StudyConfig(methods=("global",), sigmas=(5.0,), extras=(0, 1), reps=1, seed=4, workers=1, missing=(0, 1))
    study = run_study(patients, config, progress=False)
    assert sorted({r["n_missing"] for r in study.rows}) == [0, 1]
    claims = study.claims["global"]
    expected_claims = sum(len(p.nodes) - k + e for p in patients for k in (0, 1) for e in (0, 1))
    assert len(claims["confidence"]) == expected_claims and claims["extra"].sum() == 2 * 2
    bounds = study.bounds["global"]
    assert len(bounds["bound_mm"]) == 2 * 2 and np.all(bounds["bound_mm"] > 0)    # one left out per trial with missing
    stored = {(r["patient"], r["stored"]) for r in study.incremental}
    assert {s for _, s in stored} == set(range(3, max(len(p.nodes) for p in patients) + 1))   # rep 0: extras[0] = 0
    text = write_report(study, tmp_path, "snreg simulate --missing 0,1")["markdown"].read_text()
    for heading in ("With SPECT nodes not found", "target-error bound coverage", "Incremental", "Claims of every"):
        assert heading in text
    # the thesis protocol alone (missing 0) has no incremental scenario and Table 6 counts only its trials
    plain = run_study(patients, StudyConfig(**{**config.__dict__, "missing": (0,)}), progress=False)
    assert plain.incremental == [] and "Incremental" not in write_report(plain, tmp_path / "plain")["markdown"].read_text()
    assert [r["success"] for r in plain.rows] == [r["success"] for r in study.rows if r["n_missing"] == 0]


def test_a_refused_trial_is_a_failure_under_every_pairing_rule():
    from snreg.registration.pairing import RULES
    from snreg.simulation import protocol

    patient = synthetic_cohort()[6]                     # 7 nodes: enough to say the 1 degree, 1 mm bounds are wrong
    trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 5.0, 1, 0, (1, 6, 0, 1, 0))
    outcome = protocol.run_trial(trial, "global", max_rotation_deg=1.0, max_translation_mm=1.0)
    assert outcome.row["refused"] and not outcome.row["success"] and not outcome.row["all_claims"]
    assert all(outcome.row[f"success_{rule}"] is False for rule in RULES)


def test_a_trial_whose_labels_let_fewer_than_three_nodes_pair_is_refused_not_a_crash():
    # The incremental scenario's first three stores can all be left nodes (one an extra) where the patient has two
    # left hot spots: the registration refuses (TooFewPairsError), and the study counts a failure instead of stopping.
    from dataclasses import replace

    from snreg.simulation import protocol

    patient = synthetic_cohort()[6]
    trial = make_trial(patient.name, patient.nodes.xyz, patient.nodes.labels, 5.0, 0, 0, (1, 6, 0, 1, 0))
    left = set(trial.truth[:2].tolist())                 # the hot spots of the first two stored nodes are the left ones
    part = replace(trial, intraop=trial.intraop[:3], truth=trial.truth[:3], source=None, intraop_cov=None,
                   intraop_labels=["L", "L", "L"],
                   preop_labels=["L" if k in left else "R" for k in range(len(trial.preop))])
    outcome = protocol.run_trial(part, "global", use_labels=True)
    assert outcome.row["refused"] and not outcome.row["success"]
