"""snreg.preop.segment on synthetic SPECT written as real NM DICOM (thesis §3.2 phantom, 4.795 mm voxels)."""

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from snreg.demo.spect import THESIS_SOURCES, THESIS_VOXEL_MM, spect_of_nodes, write_nm
from snreg.preop import PreopError, load_volume, segment_nodes
from snreg.simulation.cohort import synthetic_cohort

CENTRE_TOLERANCE_MM = 1.0


def scan(tmp_path, xyz, seed=0, **kwargs):
    counts, origin = spect_of_nodes(xyz, seed=seed, **kwargs)
    return load_volume(write_nm(counts, origin, THESIS_VOXEL_MM, tmp_path / f"spect{seed}.dcm")[0])


def matched_errors(found, truth):
    distances = cdist(found, truth)
    assert len(set(distances.argmin(axis=1))) == len(truth) == len(found)
    return distances.min(axis=1)


def test_thesis_phantom_centres_within_1_mm_and_sides_labelled(tmp_path):
    result = segment_nodes(scan(tmp_path, THESIS_SOURCES))
    assert matched_errors(result.nodes.xyz, THESIS_SOURCES).max() < CENTRE_TOLERANCE_MM
    assert result.nodes.frame == "LPS" and result.nodes.ids == ["P1", "P2", "P3", "P4"]
    for xyz, label in zip(result.nodes.xyz, result.nodes.labels):
        assert label == ("L" if xyz[0] > 0 else "R")      # LPS: +x is the patient's left
    assert result.clusters.max() == 4 and result.threshold > 0


@pytest.mark.parametrize("seed", range(4))
def test_off_grid_sources_within_1_mm(tmp_path, seed):
    truth = THESIS_SOURCES + np.random.default_rng(seed).uniform(-2.4, 2.4, size=THESIS_SOURCES.shape)
    result = segment_nodes(scan(tmp_path, truth, seed=seed))
    assert matched_errors(result.nodes.xyz, truth).max() < CENTRE_TOLERANCE_MM


def test_cohort_patient_nodes_are_found(tmp_path):
    patient = synthetic_cohort()[4]
    result = segment_nodes(scan(tmp_path, patient.nodes.xyz), n_nodes=len(patient.nodes))
    assert matched_errors(result.nodes.xyz, patient.nodes.xyz).max() < 3.0   # merged neighbours bias each other


@pytest.mark.parametrize("direction", [(1, 0, 0), (1, 1, 1)])
def test_two_nodes_15_mm_apart_split_into_two(tmp_path, direction):
    step = 15.0 * np.asarray(direction, float) / np.linalg.norm(direction)
    truth = np.array([[-40.0, 30.0, 20.0], [-40.0, 30.0, 20.0] + step])
    volume = scan(tmp_path, truth, seed=2)
    for n_nodes in (None, 2):
        result = segment_nodes(volume, n_nodes=n_nodes)
        assert matched_errors(result.nodes.xyz, truth).max() < 2.0


def test_expected_count_splits_nodes_merged_without_a_dip(tmp_path):
    truth = np.array([[-40.0, 30.0, 20.0], [-30.0, 30.0, 20.0]])     # 10 mm: one hot spot, one peak
    volume = scan(tmp_path, truth, seed=3)
    assert len(segment_nodes(volume).nodes) == 1
    assert matched_errors(segment_nodes(volume, n_nodes=2).nodes.xyz, truth).max() < 4.0


def test_sorted_by_activity_and_expected_count_keeps_the_hottest(tmp_path):
    activity = np.array([0.5, 1.0, 0.8, 0.6])
    volume = scan(tmp_path, THESIS_SOURCES, activity=activity)
    result = segment_nodes(volume, threshold=0.2)
    hottest_first = THESIS_SOURCES[np.argsort(-activity)]
    np.testing.assert_allclose(result.nodes.xyz, hottest_first, atol=CENTRE_TOLERANCE_MM)
    assert np.all(np.diff(result.total_counts) < 0) and np.all(result.peak_counts <= result.total_counts)
    np.testing.assert_allclose(segment_nodes(volume, n_nodes=2).nodes.xyz, hottest_first[:2], atol=CENTRE_TOLERANCE_MM)


def test_threshold_above_weak_nodes_drops_them(tmp_path):
    volume = scan(tmp_path, THESIS_SOURCES, activity=[1.0, 1.0, 0.2, 0.2])   # higher echelons at 20 %
    assert len(segment_nodes(volume, threshold=0.3).nodes) == 2
    assert len(segment_nodes(volume, threshold=0.1).nodes) == 4


def test_stations_and_midline(tmp_path):
    volume = scan(tmp_path, THESIS_SOURCES)
    result = segment_nodes(volume, stations={"P1": "EXT", "P3": "INT"}, midline_x=100.0)
    assert result.nodes.labels[0] == "EXT R" and result.nodes.labels[2] == "INT R"
    assert set(result.nodes.labels) <= {"EXT R", "INT R", "R"}


def test_station_table_naming_no_node_found_is_refused(tmp_path):
    """A table written for the old ids (SN1...) must not label nothing silently."""
    with pytest.raises(PreopError, match="names SN1, but the nodes found are P1 to P4"):
        segment_nodes(scan(tmp_path, THESIS_SOURCES), stations={"SN1": "EXT"})


def test_bad_parameters_and_empty_volumes(tmp_path):
    volume = scan(tmp_path, THESIS_SOURCES)
    with pytest.raises(PreopError, match="between 0 and 1"):
        segment_nodes(volume, threshold=1.5)
    with pytest.raises(PreopError, match="at least 1"):
        segment_nodes(volume, n_nodes=0)
    flat = type(volume)(np.zeros((4, 4, 4), np.float32), np.eye(4), "NM")
    with pytest.raises(PreopError, match="no activity"):
        segment_nodes(flat)
